// Bus tools the trace and PDO pages share: the bus's SYNC producer
// (GET|PUT /buses/{bus}/sync), started, stopped and its period set from
// the page, and who may use the tools that send on the bus. The gateway
// asks an operator's or an admin's token for every one of them (SYNC, raw
// frames, RPDOs) and audits them; a viewer's page shows them disabled,
// with why.

import { api, runAction } from './api.js';
import { whenSignedIn } from './auth.js';
import { h } from './dom.js';

/** How often the SYNC state is read again (another client may change it). */
const SYNC_POLL_MS = 3000;

/**
 * Why the signed-in user may not send on the bus, or '' when they may.
 * Resolves once the gateway said who the page is.
 */
export async function sendRefusal() {
  const me = await whenSignedIn();
  if (!me || !me.auth_required || me.role === 'admin' || me.role === 'operator') return '';
  return `Sending on the bus needs an operator or admin token; this page is signed in as ${me.role}.`;
}

/** Disables `controls` (elements) and says `reason` in `note`, or enables them. */
export function applyRefusal(reason, controls, note) {
  for (const el of controls) {
    el.disabled = Boolean(reason);
    if (reason) el.title = reason;
    else el.removeAttribute('title');
  }
  note.textContent = reason;
  note.hidden = !reason;
}

/**
 * The SYNC control: state, a period in ms and Start/Stop, in a new element;
 * the state is read again every few seconds while the page is shown.
 * `onState(state)` hears every state read or set ({period_ms, cob_id}).
 */
export function syncControl(bus, { onState = () => {} } = {}) {
  const path = `/buses/${encodeURIComponent(bus)}/sync`;
  const state = h('span', { id: 'sync-state', class: 'sync-state', role: 'status', 'aria-live': 'polite' }, 'Reading SYNC…');
  const period = h('input', {
    id: 'sync-period', name: 'period_ms', type: 'number', min: 1, max: 60000, step: 1, value: 10,
    inputmode: 'numeric', 'aria-label': 'SYNC period in ms',
  });
  const start = h('button', { id: 'sync-start', class: 'button', type: 'button' }, 'Start SYNC');
  const stop = h('button', { id: 'sync-stop', class: 'button', type: 'button' }, 'Stop SYNC');
  const note = h('span', { class: 'tool-refusal', hidden: true });
  const error = h('span', { id: 'sync-error', class: 'row-error', role: 'alert' });
  const box = h('div', { id: 'sync-control', class: 'tool-row sync-control', dataset: { periodMs: '' } },
    h('strong', {}, 'SYNC'), state,
    h('label', { class: 'sync-period' }, 'every ', period, ' ms'), start, stop, note, error);

  let refusal = '';
  function show(sync) {
    const on = sync.period_ms > 0;
    box.dataset.periodMs = String(sync.period_ms);
    state.dataset.state = on ? 'on' : 'off';
    state.textContent = on ? `running, every ${sync.period_ms} ms` : 'off';
    if (on && document.activeElement !== period) period.value = sync.period_ms;
    start.textContent = on ? 'Set period' : 'Start SYNC';
    if (!refusal) stop.disabled = !on;
    onState(sync);
  }

  async function set(button, periodMs) {
    error.textContent = '';
    const result = await runAction(button, periodMs ? 'Starting…' : 'Stopping…',
      () => api(path, { method: 'PUT', body: { period_ms: periodMs } }));
    if (result.ok) show(result.value);
    else error.textContent = `SYNC: ${result.error.message}`;
  }

  start.addEventListener('click', () => {
    const ms = Number(period.value);
    if (!Number.isInteger(ms) || ms < 1 || ms > 60000) {
      error.textContent = 'SYNC period: a whole number of ms from 1 to 60000';
      period.setAttribute('aria-invalid', 'true');
      return;
    }
    period.removeAttribute('aria-invalid');
    set(start, ms);
  });
  stop.addEventListener('click', () => set(stop, 0));

  async function load() {
    try {
      show(await api(path));
    } catch (e) {
      state.textContent = 'unknown';
      error.textContent = `SYNC: ${e.message}`;
    }
  }

  sendRefusal().then((reason) => {
    refusal = reason;
    applyRefusal(reason, [period, start, stop], note);
    if (!reason) stop.disabled = box.dataset.periodMs === '0';
  });
  load();
  setInterval(() => { if (!document.hidden) load(); }, SYNC_POLL_MS);
  return { element: box, reload: load };
}
