// The REST API from the browser: one fetch wrapper that turns the API's
// {"error":{"code","message",...}} bodies (and network failures) into
// ApiError messages a person can read, and runAction, which shows on the
// button that started an action that it is in progress. Requests carry the
// signed-in token and wait for a sign-in when the gateway asks for one
// (auth.js).

import { authorization, signInAgain, whenSignedIn } from './auth.js';

export class ApiError extends Error {
  constructor(message, { status = 0, code = 'network', body = null } = {}) {
    super(message);
    this.name = 'ApiError';
    this.status = status;
    this.code = code;
    this.body = body;
  }
}

/** The human text of an API error body, with its code and SDO details. */
export function describeError(status, body, fallback) {
  const error = body && typeof body === 'object' ? body.error : null;
  if (!error || typeof error.message !== 'string') return fallback || `HTTP ${status}`;
  const details = [error.code];
  if (error.abort_code) details.push(`abort ${error.abort_code}`);
  if (error.step) details.push(`at step ${error.step}`);
  return `${error.message} (${details.filter(Boolean).join(', ')})`;
}

/**
 * Calls `/api/v1${path}` and returns the decoded JSON body (null when
 * empty); `headers` are added to the request's. Throws ApiError: status 0 when the gateway cannot be reached.
 */
export async function api(path, { method = 'GET', body, signal, headers = {} } = {}) {
  await whenSignedIn();
  const init = { method, signal, headers: { accept: 'application/json', ...authorization(), ...headers } };
  if (body !== undefined) {
    init.headers['content-type'] = 'application/json';
    init.body = JSON.stringify(body);
  }
  let response;
  try {
    response = await fetch(`/api/v1${path}`, init);
  } catch (err) {
    if (err.name === 'AbortError') throw err;
    throw new ApiError(`cannot reach the gateway (${method} ${path}): ${err.message}`);
  }
  const text = await response.text();
  let data = null;
  if (text) {
    try {
      data = JSON.parse(text);
    } catch {
      throw new ApiError(`${method} ${path}: HTTP ${response.status}, and the answer is not JSON`, {
        status: response.status, code: 'bad_response',
      });
    }
  }
  if (response.status === 401) signInAgain();
  if (!response.ok) {
    const code = data?.error?.code || `http_${response.status}`;
    throw new ApiError(describeError(response.status, data, `${method} ${path}: HTTP ${response.status} ${response.statusText}`), {
      status: response.status, code, body: data,
    });
  }
  return data;
}

/**
 * `fetch` of `/api/v1${path}` for what is not JSON (a DCF, an EDS file):
 * like api(), it waits for a sign-in, carries the page's token and asks
 * for a new sign-in on a 401; `init` is fetch's. Returns the Response, or
 * throws ApiError (status 0) when the gateway cannot be reached.
 */
export async function apiFetch(path, init = {}) {
  await whenSignedIn();
  const method = init.method || 'GET';
  let response;
  try {
    response = await fetch(`/api/v1${path}`, { ...init, headers: { ...(init.headers || {}), ...authorization() } });
  } catch (err) {
    if (err.name === 'AbortError') throw err;
    throw new ApiError(`cannot reach the gateway (${method} ${path}): ${err.message}`);
  }
  if (response.status === 401) signInAgain();
  return response;
}

/**
 * Runs `action` (an async function) as the button's action: while it runs
 * the button is disabled, says `busyLabel` and has aria-busy; afterwards
 * it gets its label back and data-state "done" or "failed". Returns
 * {ok: true, value} or {ok: false, error}, never throws.
 */
export async function runAction(button, busyLabel, action) {
  const label = button.textContent;
  button.disabled = true;
  button.setAttribute('aria-busy', 'true');
  button.dataset.state = 'busy';
  button.textContent = busyLabel;
  try {
    const value = await action();
    button.dataset.state = 'done';
    return { ok: true, value };
  } catch (error) {
    button.dataset.state = 'failed';
    return { ok: false, error };
  } finally {
    button.textContent = label;
    button.disabled = false;
    button.removeAttribute('aria-busy');
  }
}
