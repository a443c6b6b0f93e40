// Signing in to a gateway that asks for tokens (docs/security.md). The
// token is kept for this tab (sessionStorage) or, with "Remember on this
// device", in localStorage; api.js sends it as
// `Authorization: Bearer`, stream.js as the WebSocket subprotocol
// `bearer.TOKEN` (a browser cannot set headers on a WebSocket). Until the
// gateway accepts a token, API calls and the stream wait for it: one
// 401 (GET /auth/whoami) shows the sign-in form, and nothing else is
// asked in vain.

import { h } from './dom.js';

const KEY = 'candeck.token';
export const STREAM_PROTOCOL = 'candeck.v1';

let ready = null; // Promise of the whoami answer (null: the gateway could not be asked)
let dialog = null;

/** The stored token, or null. */
export function token() {
  return sessionStorage.getItem(KEY) || localStorage.getItem(KEY);
}

/** The headers that carry the token (none without one). */
export function authorization() {
  const t = token();
  return t ? { authorization: `Bearer ${t}` } : {};
}

/** The stream's subprotocols: ours, and the token as a second one. */
export function protocols() {
  const t = token();
  return t ? [STREAM_PROTOCOL, `bearer.${t}`] : [STREAM_PROTOCOL];
}

/** Resolves once the gateway accepts this page (signed in, or no token needed). */
export function whenSignedIn() {
  if (!ready) ready = check();
  return ready;
}

/** The gateway answered 401 to a request: the token is gone or was never
 * valid; ask for one again. */
export function signInAgain() {
  forget();
  if (dialog?.open) return;
  ready = check();
}

function forget() {
  sessionStorage.removeItem(KEY);
  localStorage.removeItem(KEY);
}

async function check() {
  let message = '';
  for (;;) {
    let response;
    try {
      response = await fetch('/api/v1/auth/whoami', { headers: { accept: 'application/json', ...authorization() } });
    } catch {
      return null; // unreachable: api() and the stream say so themselves
    }
    if (response.status !== 401) {
      const me = response.ok ? await response.json().catch(() => null) : null;
      showUser(me);
      return me;
    }
    if (token()) message = 'The gateway does not know this token.';
    forget();
    await askForToken(message);
  }
}

/** Shows the sign-in form until a token is entered; stores it. */
function askForToken(message) {
  return new Promise((resolve) => {
    const field = h('input', {
      id: 'signin-token', name: 'token', type: 'password', autocomplete: 'current-password',
      required: true, spellcheck: 'false', 'aria-describedby': 'signin-error',
    });
    const remember = h('input', { id: 'signin-remember', type: 'checkbox' });
    const error = h('p', { id: 'signin-error', class: 'signin-error', role: 'alert' }, message);
    error.hidden = !message;
    const form = h('form', {
      method: 'dialog', class: 'signin',
      on: {
        submit: (event) => {
          event.preventDefault();
          const value = field.value.trim();
          if (!value) return;
          (remember.checked ? localStorage : sessionStorage).setItem(KEY, value);
          dialog.close();
          dialog.remove();
          dialog = null;
          resolve();
        },
      },
    },
    h('h2', {}, 'Sign in'),
    h('p', {}, 'This gateway asks for an access token. Your administrator gives you one with a role: viewer, operator or admin.'),
    h('label', { for: 'signin-token' }, 'Access token'),
    field,
    h('label', { class: 'signin-remember' }, remember, ' Remember on this device'),
    error,
    h('button', { type: 'submit', class: 'primary' }, 'Sign in'));
    dialog = h('dialog', { id: 'signin', 'aria-labelledby': 'signin-title' }, form);
    form.querySelector('h2').id = 'signin-title';
    // Esc would leave a page that waits for nothing.
    dialog.addEventListener('cancel', (event) => event.preventDefault());
    document.body.append(dialog);
    dialog.showModal();
    field.focus();
  });
}

/** The signed-in name and role in the top bar, with a sign-out link. */
function showUser(me) {
  document.getElementById('user')?.remove();
  if (!me || !me.auth_required) return;
  const signOut = h('a', {
    href: '#', class: 'signout',
    on: { click: (event) => { event.preventDefault(); forget(); window.location.reload(); } },
  }, 'Sign out');
  const user = h('span', { id: 'user', class: 'user', dataset: { role: me.role } },
    h('span', { class: 'user-name' }, me.name), h('span', { class: 'role' }, me.role), signOut);
  const bar = document.querySelector('.topbar');
  bar?.insertBefore(user, document.getElementById('connection'));
}
