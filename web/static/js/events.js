// The events page: the gateway's persisted history (GET /events: EMCYs,
// NMT and supervision events, the audit log of every operation that
// changed or tried to change something, whichever door it came through),
// newest first, filtered by kind, paged back with "Load older".
// The stream's `emcy` and `nodes` events make the page read what the
// history has recorded since its newest entry, so new entries appear
// without a reload and are always the stored ones, with their ids.

import { api } from './api.js';
import { $, h, showMessage, updateRows } from './dom.js';
import { stream } from './layout.js';

const PAGE = 100;

const tbody = $('#history tbody');
const olderButton = $('#load-older');
const count = $('#history-count');
const pageMessage = $('#page-message');
const kindButtons = [...document.querySelectorAll('.kinds button')];

let kind = '';
let entries = new Map(); // "kind:id" -> entry
let exhausted = false; // nothing older than what is shown
let generation = 0; // a new filter makes answers to the old one stale

const entryKey = (e) => `${e.kind}:${e.id}`;
const byTime = (a, b) => b.time_us - a.time_us || (a.kind < b.kind ? 1 : a.kind > b.kind ? -1 : b.id - a.id);

function query(params) {
  const search = new URLSearchParams({ limit: String(PAGE), ...params });
  if (kind) search.set('kind', kind);
  return `/events?${search}`;
}

/** Adds entries; returns how many were new. */
function merge(list) {
  let fresh = 0;
  for (const e of list) {
    if (!entries.has(entryKey(e))) fresh += 1;
    entries.set(entryKey(e), e);
  }
  return fresh;
}

// ---- rendering -------------------------------------------------------------

const pad = (n, width = 2) => String(n).padStart(width, '0');

/** Local date and time to the millisecond. */
function when(timeUs) {
  const d = new Date(Math.floor(timeUs / 1000));
  return `${d.getFullYear()}-${pad(d.getMonth() + 1)}-${pad(d.getDate())} ${pad(d.getHours())}:${pad(d.getMinutes())}:${pad(d.getSeconds())}.${pad(d.getMilliseconds(), 3)}`;
}

const NMT = {
  boot_up: 'boot-up', pre_operational: 'pre-operational', operational: 'operational',
  stopped: 'stopped', unknown: 'unknown',
};
const state = (s) => NMT[s] || s;

function where(e) {
  if (!e.bus) return '—';
  const parts = [e.bus];
  if (e.node !== undefined) parts.push(`node ${e.node}`);
  if (e.axis !== undefined) parts.push(`axis ${e.axis}`);
  const text = parts.join(' · ');
  if (e.node === undefined) return text;
  return h('a', { href: `/nodes/${encodeURIComponent(e.bus)}/${e.node}` }, text);
}

function nmtText(e) {
  switch (e.event) {
    case 'appeared': return 'appeared on the bus';
    case 'identified': return `identified${e.reason ? `: ${e.reason}` : ''}`;
    case 'identification_failed': return `could not be identified${e.reason ? `: ${e.reason}` : ''}`;
    case 'nmt_changed': return `NMT ${state(e.from)} → ${state(e.to)}`;
    case 'offline': return `went offline${e.reason ? ` (${e.reason.replaceAll('_', ' ')})` : ''}`;
    case 'online': return 'back online';
    case 'heartbeat_written': return `heartbeat time written: ${e.reason || '—'}`;
    case 'lost': return `events not recorded: ${e.reason || 'some'}`;
    default: return e.event || '—';
  }
}

function what(e) {
  if (e.kind === 'emcy') {
    return [h('span', { class: 'emcy' }, h('code', {}, e.code), ' ', e.text || ''),
      h('div', { class: 'sub' }, `error register 0x${(e.register ?? 0).toString(16).toUpperCase().padStart(2, '0')}`,
        e.manufacturer ? ` · manufacturer ${e.manufacturer}` : '')];
  }
  if (e.kind === 'nmt') return nmtText(e);
  // The door it came through; its own words for the request (REST's
  // method and path, a CiA 309-3 command line, a Sparkplug topic) when it
  // has them: the gateway's own entries and the stream's have none.
  const detail = e.method || e.path ? h('code', {}, [e.method, e.path].filter(Boolean).join(' ')) : null;
  return [h('strong', { class: 'operation' }, e.operation || e.method || '—'),
    e.item ? ' ' : null,
    e.item ? h('code', { class: 'item' }, e.item) : null,
    h('div', { class: 'sub' }, h('span', { class: 'channel' }, channelName(e.channel)), detail ? ' · ' : null, detail),
    e.request ? h('div', { class: 'request' }, h('code', {}, e.request)) : null];
}

const CHANNELS = {
  rest: 'REST', websocket: 'stream', cia309_3: 'CiA 309-3', cia309_5: 'CiA 309-5',
  sparkplug: 'Sparkplug', opcua: 'OPC UA', system: 'gateway',
};
const channelName = (c) => CHANNELS[c] || c || '—';

function who(e) {
  if (e.kind !== 'audit') return h('span', { class: 'sub' }, 'device');
  return [e.who || '—', h('div', { class: 'sub' }, `role ${e.role || '—'}${e.peer ? ` · ${e.peer}` : ''}`)];
}

function outcome(e) {
  if (e.kind !== 'audit') return '';
  // `outcome` is `ok` or the error's code; the HTTP status REST answered
  // leads where there is one.
  const ok = e.outcome === 'ok';
  const code = ok ? null : (e.outcome || e.error_code || '—');
  const badge = e.status !== undefined ? String(e.status) : ok ? 'ok' : 'failed';
  return [h('span', { class: `badge ${ok ? 'ok' : 'bad'}` }, badge),
    code ? ' ' : null,
    code ? h('code', { class: 'error-code' }, code) : null,
    e.abort_code ? h('div', { class: 'abort' }, 'SDO abort ', h('code', {}, e.abort_code)) : null];
}

function render() {
  const list = [...entries.values()].sort(byTime);
  count.textContent = list.length ? `${list.length} entries, newest first` : '';
  olderButton.hidden = exhausted || list.length === 0;
  if (list.length === 0) {
    tbody.replaceChildren(h('tr', { class: 'placeholder' }, h('td', { colspan: 6 }, 'No event recorded yet.')));
    return;
  }
  // Only what changed is replaced: a row under a finger (its node's link)
  // or being selected stays while newer events come in.
  updateRows(tbody, list.map((e) => h('tr', { dataset: { kind: e.kind, id: e.id, key: `${e.kind}/${e.id}` }, class: `k-${e.kind}` },
    h('td', { 'data-label': 'Time', class: 'time' }, h('time', { datetime: e.time, title: e.time }, when(e.time_us))),
    h('td', { 'data-label': 'Kind' }, h('span', { class: `kind kind-${e.kind}` }, e.kind.toUpperCase())),
    h('td', { 'data-label': 'Where' }, where(e)),
    h('td', { 'data-label': 'What' }, what(e)),
    h('td', { 'data-label': 'Who' }, who(e)),
    h('td', { 'data-label': 'Result' }, outcome(e)))));
}

// ---- loading ---------------------------------------------------------------

async function loadNewest() {
  const mine = ++generation;
  entries = new Map();
  exhausted = false;
  tbody.replaceChildren(h('tr', { class: 'placeholder' }, h('td', { colspan: 6 }, 'Loading…')));
  try {
    const list = await api(query({}));
    if (mine !== generation) return;
    merge(list);
    exhausted = list.length < PAGE;
    showMessage(pageMessage, '');
  } catch (error) {
    if (mine !== generation) return;
    showMessage(pageMessage, `Events: ${error.message}`);
  }
  render();
}

olderButton.addEventListener('click', async () => {
  const mine = generation;
  const oldest = [...entries.values()].sort(byTime).pop();
  olderButton.disabled = true;
  olderButton.setAttribute('aria-busy', 'true');
  olderButton.textContent = 'Loading older…';
  try {
    // `until` includes the oldest entry's own time: entries sharing it are
    // not missed, and the ones already here are dropped by kind and id.
    const list = await api(query({ until: oldest.time }));
    if (mine !== generation) return;
    const fresh = merge(list);
    exhausted = list.length < PAGE || fresh === 0;
    showMessage(pageMessage, '');
  } catch (error) {
    showMessage(pageMessage, `Older events: ${error.message}`);
  } finally {
    olderButton.disabled = false;
    olderButton.removeAttribute('aria-busy');
    olderButton.textContent = 'Load older';
  }
  render();
});

let newerTimer = null;
let newerRunning = false;

/** Reads what the history recorded since the newest entry shown. */
async function loadNewer(retries) {
  if (newerRunning) {
    scheduleNewer(retries);
    return;
  }
  newerRunning = true;
  const mine = generation;
  const newest = [...entries.values()].sort(byTime)[0];
  let fresh = 0;
  try {
    const list = await api(newest ? query({ since: newest.time, limit: '1000' }) : query({}));
    if (mine === generation) fresh = merge(list);
    showMessage(pageMessage, '');
  } catch (error) {
    showMessage(pageMessage, `Events: ${error.message}`);
  } finally {
    newerRunning = false;
  }
  if (fresh) render();
  // The stream can tell of an event a moment before the history has
  // written it: look again a little later when nothing new was there.
  else if (retries > 0) scheduleNewer(retries - 1, 700);
}

function scheduleNewer(retries = 2, delay = 150) {
  clearTimeout(newerTimer);
  newerTimer = setTimeout(() => loadNewer(retries), delay);
}

const wanted = (topicKind) => kind === '' || kind === topicKind;

stream.subscribe(['emcy'], () => { if (wanted('emcy') || wanted('audit')) scheduleNewer(); });
stream.subscribe(['nodes'], () => { if (wanted('nmt') || wanted('audit')) scheduleNewer(); });

// Audit entries have no stream topic: while the gateway is there, the
// page asks for what is new every few seconds.
const POLL_MS = 5000;
let poll = null;

stream.onState(({ state: connection, reconnected }) => {
  clearInterval(poll);
  if (connection !== 'connected') return;
  if (reconnected) scheduleNewer(0, 0);
  poll = setInterval(() => scheduleNewer(0, 0), POLL_MS);
});

for (const button of kindButtons) {
  button.addEventListener('click', () => {
    kind = button.dataset.kind;
    for (const b of kindButtons) b.setAttribute('aria-pressed', String(b === button));
    const url = new URL(window.location.href);
    if (kind) url.searchParams.set('kind', kind);
    else url.searchParams.delete('kind');
    window.history.replaceState(null, '', url);
    loadNewest();
  });
}

// A link may name the kind: /events?kind=audit.
const asked = new URLSearchParams(window.location.search).get('kind');
const start = kindButtons.find((b) => b.dataset.kind === asked);
if (start && asked) {
  kind = asked;
  for (const b of kindButtons) b.setAttribute('aria-pressed', String(b === start));
}

stream.connect();
loadNewest();
