// The overview page: buses, nodes, the machine (the network manager's
// view: expected and found nodes, their boot-up and supervision), STOP ALL
// and the recent events. Tables
// show what the gateway read from the devices; a stream event only says
// that something changed, and the node is then read again over REST.

import { api, runAction } from './api.js';
import { axisFault } from './axes.js';
import { stateLabel } from './cia402.js';
import { $, clock, h, showMessage, updateRows } from './dom.js';
import { stream } from './layout.js';
import { onAlarms, SEVERITIES } from './alarmbar.js';
import { recoveryControls } from './recovery.js';

const BUS_POLL_MS = 1000;
// The axes' states on the overview: a few samples a second are enough.
const AXIS_RATE_HZ = 2;
const MAX_EVENTS = 50;

const busBody = $('#buses tbody');
const nodeBody = $('#nodes tbody');
const eventList = $('#events');
const pageMessage = $('#page-message');

const buses = new Map(); // name -> {info, fps, sample: {frames, at}}
const nodes = new Map(); // "bus/id" -> {bus, node, detail, error, loading, again}
let busTimer = null;
const problems = new Map(); // what failed -> message, shown at the top

function problem(key, text) {
  if (text) problems.set(key, text);
  else problems.delete(key);
  showMessage(pageMessage, [...problems.values()].join(' · '));
}

// ---- buses ---------------------------------------------------------------

async function loadBuses() {
  let list;
  try {
    list = await api('/buses');
  } catch (error) {
    problem('buses', `Buses: ${error.message}`);
    return null;
  }
  problem('buses', null);
  const now = performance.now();
  const seen = new Set();
  for (const info of list) {
    seen.add(info.name);
    const frames = info.rx_frames + info.tx_frames;
    const old = buses.get(info.name);
    // Counters that went down belong to a gateway that restarted: the rate
    // waits for a second sample of the new one.
    let fps = null;
    if (old && now > old.sample.at && frames >= old.sample.frames) {
      fps = ((frames - old.sample.frames) * 1000) / (now - old.sample.at);
    }
    buses.set(info.name, { info, fps, sample: { frames, at: now } });
  }
  for (const name of buses.keys()) if (!seen.has(name)) buses.delete(name);
  renderBuses();
  return list;
}

function renderBuses() {
  if (buses.size === 0) {
    busBody.replaceChildren(h('tr', { class: 'placeholder' }, h('td', { colspan: 7 }, 'The gateway serves no bus.')));
    return;
  }
  updateRows(busBody, [...buses.values()].map(({ info, fps }) => h('tr', { dataset: { bus: info.name, key: info.name } },
    h('td', { 'data-label': 'Bus' }, h('strong', {}, h('a', { href: `/buses/${encodeURIComponent(info.name)}/trace`, title: `Trace of bus ${info.name}` }, info.name)),
      h('div', { class: 'sub' }, info.spec)),
    h('td', { 'data-label': 'Kind' }, info.kind),
    h('td', { 'data-label': 'State' }, h('span', { class: `badge ${info.state === 'up' ? 'ok' : 'bad'}` }, info.state),
      info.error_state && info.error_state !== 'error_active'
        ? h('div', { class: 'sub' }, `${info.error_state.replace('_', ' ')} (TEC ${info.tx_error_counter}, REC ${info.rx_error_counter})`) : null,
      info.reason ? h('div', { class: 'sub' }, info.reason) : null),
    h('td', { 'data-label': 'Load', class: 'num' }, `${(info.load * 100).toFixed(1)} %`),
    h('td', { 'data-label': 'Frames/s', class: 'num' }, fps === null ? '…' : fps.toFixed(0)),
    h('td', { 'data-label': 'Rx', class: 'num' }, info.rx_frames.toLocaleString()),
    h('td', { 'data-label': 'Tx', class: 'num' }, info.tx_frames.toLocaleString()),
  )));
}

// Polled while the stream is up only: when it is down the gateway is
// gone, and asking it every second would only pile up failed requests.
function pollBuses() {
  clearTimeout(busTimer);
  busTimer = setTimeout(async () => {
    await loadBuses();
    if (stream.state === 'connected') pollBuses();
  }, BUS_POLL_MS);
}

// ---- nodes ---------------------------------------------------------------

const key = (bus, id) => `${bus}/${id}`;

async function loadNodes(list) {
  const found = new Set();
  const failed = new Set(); // buses whose rows stay as they were
  await Promise.all(list.map(async ({ name }) => {
    let listed;
    try {
      listed = await api(`/buses/${encodeURIComponent(name)}/nodes`);
    } catch (error) {
      problem(`nodes ${name}`, `Nodes of ${name}: ${error.message}`);
      failed.add(name);
      return;
    }
    problem(`nodes ${name}`, null);
    for (const node of listed) {
      found.add(key(name, node.id));
      const entry = nodes.get(key(name, node.id)) || { bus: name, node, detail: null };
      entry.node = node;
      nodes.set(key(name, node.id), entry);
    }
  }));
  for (const [k, entry] of nodes) if (!found.has(k) && !failed.has(entry.bus)) nodes.delete(k);
  renderNodes();
  for (const entry of nodes.values()) refreshNode(entry.bus, entry.node.id);
}

/** Reads one node again (its registry entry and EMCY history); a read
 * asked for while one runs is done once after it, not dropped. */
async function refreshNode(bus, id) {
  const k = key(bus, id);
  let entry = nodes.get(k);
  if (!entry) {
    entry = { bus, node: { id }, detail: null };
    nodes.set(k, entry);
  }
  if (entry.loading) {
    entry.again = true;
    return;
  }
  entry.loading = true;
  try {
    const detail = await api(`/buses/${encodeURIComponent(bus)}/nodes/${id}`);
    entry.node = detail;
    entry.detail = detail;
    entry.error = null;
    entry.axes = new Map((detail.axes || []).map((a) => [a.axis, a]));
    watchAxes(entry);
  } catch (error) {
    if (error.code === 'unknown_node') nodes.delete(k);
    else entry.error = error.message;
  } finally {
    entry.loading = false;
  }
  renderNodes();
  if (entry.again && nodes.has(k)) {
    entry.again = false;
    refreshNode(bus, id);
  }
}

const NMT = {
  boot_up: 'boot-up', pre_operational: 'pre-operational', operational: 'operational',
  stopped: 'stopped', unknown: 'unknown',
};

function lastEmcy(detail) {
  const list = detail && detail.emcy;
  if (!list) return h('span', { class: 'sub' }, '…');
  if (list.length === 0) return h('span', { class: 'sub' }, 'none');
  const last = list[list.length - 1];
  return h('span', { class: 'emcy' }, h('code', {}, last.code), ' ', last.text);
}

/** Each axis of a drive as a badge: its own state and, in fault, its
 * own cause (issue 21: a node's last EMCY hides nothing of an axis). */
function axisBadges(bus, node, entry) {
  if (!entry.axes || entry.axes.size === 0) {
    return h('span', { class: 'sub' }, entry.detail && entry.detail.summary_error ? 'not read' : '—');
  }
  return h('ul', { class: 'axis-list' }, [...entry.axes.values()].map((status) => {
    const { faulted, cause } = axisFault(entry.detail, status);
    const href = `/nodes/${encodeURIComponent(bus)}/${node.id}/axes/${status.axis}`;
    return h('li', { dataset: { axis: status.axis, state: status.state || '', fault: faulted ? 'yes' : 'no' } },
      h('a', { href, class: `axis-badge${faulted ? ' fault' : status.state === 'operation_enabled' ? ' on' : ''}` },
        `Axis ${status.axis}: ${stateLabel(status.state)}`),
      faulted ? h('span', { class: 'emcy axis-cause' }, ' ', cause
        ? [h('code', {}, cause.code), ' ', cause.text] : 'cause unknown (no EMCY from this axis)') : null);
  }));
}

// The axes of the drives listed, live on their stream topics.
const axisTopics = new Map(); // topic -> {k, axis}

function watchAxes(entry) {
  const fresh = [];
  for (const axis of entry.axes.keys()) {
    const topic = `buses/${entry.bus}/nodes/${entry.node.id}/axes/${axis}`;
    if (axisTopics.has(topic)) continue;
    axisTopics.set(topic, { k: key(entry.bus, entry.node.id), axis });
    fresh.push(topic);
    stream.subscribe([topic], (data, message) => onAxisSample(topic, data, message));
  }
  if (fresh.length && stream.state === 'connected') askAxisRate(fresh);
}

function askAxisRate(topics = [...axisTopics.keys()]) {
  if (topics.length) stream.send({ op: 'subscribe', topics, max_rate_hz: AXIS_RATE_HZ });
}

function onAxisSample(topic, data, message) {
  if (message.lagged || data.error || !data.state) return;
  const { k, axis } = axisTopics.get(topic);
  const entry = nodes.get(k);
  if (!entry || !entry.axes) return;
  const old = entry.axes.get(axis);
  entry.axes.set(axis, { ...old, ...data });
  // Redrawn only on a change: a link replaced under a finger loses its tap.
  if (!old || old.state !== data.state || old.fault !== data.fault) renderNodes();
}

function renderNodes() {
  const entries = [...nodes.values()].sort((a, b) => a.bus.localeCompare(b.bus) || a.node.id - b.node.id);
  if (entries.length === 0) {
    nodeBody.replaceChildren(h('tr', { class: 'placeholder' }, h('td', { colspan: 8 }, 'No node found yet.')));
    return;
  }
  updateRows(nodeBody, entries.map((entry) => {
    const { bus, node, detail, error } = entry;
    const href = `/nodes/${encodeURIComponent(bus)}/${node.id}`;
    const online = node.online;
    return h('tr', { dataset: { bus, node: node.id, key: key(bus, node.id) }, class: online === false ? 'offline' : null },
      h('td', { 'data-label': 'Bus' }, bus),
      h('td', { 'data-label': 'Node', class: 'num' }, h('a', { href }, String(node.id))),
      h('td', { 'data-label': 'Product' }, node.name || h('span', { class: 'sub' }, node.identity ? 'no name' : '…'),
        error ? h('div', { class: 'row-error' }, error) : null),
      h('td', { 'data-label': 'Profile', class: 'profile' }, node.profile || '…'),
      h('td', { 'data-label': 'NMT', class: 'nmt' }, NMT[node.nmt] || node.nmt || '…'),
      h('td', { 'data-label': 'Online' }, online === undefined ? '…'
        : h('span', { class: `badge ${online ? 'ok' : 'bad'}` }, online ? 'online' : 'offline')),
      h('td', { 'data-label': 'Axes', class: 'axes' }, axisBadges(bus, node, entry)),
      h('td', { 'data-label': 'Last EMCY', class: 'last-emcy' }, lastEmcy(detail)),
    );
  }));
}

// ---- machine (the network manager) ---------------------------------------

const machineBody = $('#machine tbody');
const machineStates = $('#machine-states');
const machines = new Map(); // bus -> the machine as GET /buses/{bus}/machine gives it
// Machine events seen by bus: a GET answered after an event of the stream
// is older than it, and must not put an old state back.
const machineEvents = new Map();

const MACHINE_BADGE = { ready: 'ok', booting: 'warn', degraded: 'bad', down: 'bad', alarm: 'bad' };
const NODE_BADGE = {
  ready: 'ok', booting: 'warn', unexpected: 'warn',
  missing: 'bad', wrong_identity: 'bad', config_failed: 'bad', offline: 'bad',
};

async function loadMachines(list) {
  await Promise.all(list.map(async ({ name }) => {
    try {
      const seen = machineEvents.get(name) || 0;
      const machine = await api(`/buses/${encodeURIComponent(name)}/machine`);
      if ((machineEvents.get(name) || 0) === seen) machines.set(name, machine);
      problem(`machine ${name}`, null);
    } catch (error) {
      // A bus without a network manager has no machine to show.
      if (error.code !== 'invalid_request') problem(`machine ${name}`, `Machine of ${name}: ${error.message}`);
    }
  }));
  renderMachines();
}

function machineAction(bus, id, label, busy, path, body) {
  const button = h('button', { type: 'button', class: 'small', dataset: { action: label.toLowerCase().replace(' ', '-') } }, label);
  button.addEventListener('click', async () => {
    const result = await runAction(button, busy, () => api(path, { method: 'POST', body }));
    addEvent(Date.now(), result.ok ? `${bus} node ${id}: ${label.toLowerCase()} sent`
      : `${bus} node ${id}: ${label.toLowerCase()} failed: ${result.error.message}`, result.ok ? 'info' : 'warn');
  });
  return button;
}

// "Reset all faults" and "Enable all" of each bus with a machine, made
// once (a redraw of the card must not take a button away mid-tap).
const recoveryRoot = $('#machine-recovery');
const recoveries = new Map(); // bus -> its controls' element

function renderRecovery() {
  for (const bus of [...machines.keys()].sort()) {
    if (recoveries.has(bus)) continue;
    const { buttons, result } = recoveryControls(bus, () => loadMachines([{ name: bus }]));
    const el = h('div', { class: 'recovery-bus', dataset: { bus } },
      machines.size > 1 ? h('strong', {}, `${bus}: `) : null, buttons, result);
    recoveries.set(bus, el);
    recoveryRoot.append(el);
  }
}

function renderMachines() {
  renderRecovery();
  updateRows(machineStates, [...machines.entries()].map(([bus, m]) => h('p', { dataset: { bus, key: bus } },
    h('strong', {}, `${bus}: `), h('span', { class: `badge ${MACHINE_BADGE[m.state] || ''}`, dataset: { state: m.state } }, m.state),
    m.reasons.length ? h('span', { class: 'sub' }, ` ${m.reasons.join(' · ')}`) : null)));
  const rows = [];
  for (const [bus, m] of [...machines.entries()].sort()) {
    for (const n of m.nodes) {
      const base = `/buses/${encodeURIComponent(bus)}`;
      rows.push(h('tr', { dataset: { bus, node: n.id, state: n.state, key: key(bus, n.id) } },
        h('td', { 'data-label': 'Bus' }, bus),
        h('td', { 'data-label': 'Node', class: 'num' }, String(n.id)),
        h('td', { 'data-label': 'Name' }, n.name || h('span', { class: 'sub' }, '—'),
          n.mandatory ? h('div', { class: 'sub' }, 'mandatory') : null),
        h('td', { 'data-label': 'Expected' }, n.expected ? 'expected' : 'found'),
        h('td', { 'data-label': 'State', class: 'machine-state' }, h('span', { class: `badge ${NODE_BADGE[n.state] || ''}` }, n.state.replace('_', ' '))),
        h('td', { 'data-label': 'Step', class: 'step' }, n.step.replace('_', ' ')),
        h('td', { 'data-label': 'Supervision', class: 'supervision' }, n.supervision),
        h('td', { 'data-label': 'NMT', class: 'nmt' }, NMT[n.nmt] || n.nmt),
        h('td', { 'data-label': 'Reason', class: 'reason' }, n.reason || ''),
        h('td', { 'data-label': 'Actions', class: 'actions' },
          machineAction(bus, n.id, 'Boot again', 'Booting…', `${base}/machine/nodes/${n.id}/boot`),
          n.state === 'missing' ? null
            : machineAction(bus, n.id, 'Start', 'Starting…', `${base}/nodes/${n.id}/nmt`, { command: 'start' })),
      ));
    }
  }
  if (rows.length === 0) {
    machineBody.replaceChildren(h('tr', { class: 'placeholder' }, h('td', { colspan: 10 }, 'No node expected or found yet.')));
    return;
  }
  updateRows(machineBody, rows);
}

stream.subscribe(['machine'], (data, message) => {
  if (message.lagged) return lagged(message);
  const { bus, ...machine } = data;
  machineEvents.set(bus, (machineEvents.get(bus) || 0) + 1);
  const old = machines.get(bus);
  if (old && old.state !== machine.state) addEvent(message.ts, `${bus}: machine ${old.state} → ${machine.state}`, machine.state === 'ready' ? 'info' : 'warn');
  machines.set(bus, machine);
  renderMachines();
});

// ---- events --------------------------------------------------------------

function addEvent(ts, text, kind, { fromHistory = false } = {}) {
  const placeholder = eventList.querySelector('.placeholder');
  if (placeholder) placeholder.remove();
  const item = h('li', { class: kind, dataset: fromHistory ? { history: 'yes' } : {} }, h('time', {}, clock(ts)), ' ', text);
  // The history's entries are older than anything the stream brought.
  if (fromHistory) eventList.append(item);
  else eventList.prepend(item);
  while (eventList.children.length > MAX_EVENTS) eventList.lastElementChild.remove();
}

const HISTORY_EVENTS = 15;

/** The newest entries of the history (GET /events), when the page opens:
 * what happened before it did. */
async function loadHistory() {
  let entries;
  try {
    entries = await api(`/events?limit=${HISTORY_EVENTS}`);
  } catch (error) {
    problem('history', `Recent events: ${error.message}`);
    entries = [];
  }
  if (entries.length) problem('history', null);
  const placeholder = eventList.querySelector('.placeholder');
  if (placeholder) placeholder.textContent = 'Nothing yet.';
  const nmtText = (e) => `${e.bus} node ${e.node}: ${e.event === 'nmt_changed' ? `NMT ${NMT[e.from] || e.from} → ${NMT[e.to] || e.to}` : (e.event || '').replaceAll('_', ' ')}${e.reason ? ` (${e.reason.replaceAll('_', ' ')})` : ''}`;
  const auditText = (e) => `${e.who || '—'}: ${e.operation || e.method || '—'}${e.item ? ` ${e.item}` : ''}${e.node !== undefined ? ` (${e.bus} node ${e.node}${e.axis !== undefined ? ` axis ${e.axis}` : ''})` : ''}${e.outcome && e.outcome !== 'ok' ? ` → ${e.outcome}` : ''}`;
  // Oldest first from the API: appended newest first.
  for (const e of [...entries].reverse()) {
    const ts = Date.parse(e.time);
    if (e.kind === 'emcy') addEvent(ts, emcyText(e), 'emcy', { fromHistory: true });
    else if (e.kind === 'nmt') addEvent(ts, nmtText(e), e.event === 'offline' ? 'warn' : 'info', { fromHistory: true });
    else addEvent(ts, auditText(e), e.outcome && e.outcome !== 'ok' ? 'warn' : 'info', { fromHistory: true });
  }
}

// ---- alarms: the summary on the machine card ---------------------------------

const alarmSummary = $('#alarm-summary');
onAlarms((alarms, s) => {
  const counts = SEVERITIES.filter((sev) => s.active[sev]).map((sev) => `${s.active[sev]} ${sev}`);
  alarmSummary.dataset.state = s.activeUnacknowledged ? 'unacknowledged' : s.activeCount ? 'active' : s.clearedUnacknowledged ? 'cleared' : 'quiet';
  alarmSummary.replaceChildren(
    h('strong', {}, s.activeCount ? `Alarms: ${counts.join(', ')} active` : 'No active alarms'),
    s.activeUnacknowledged ? ` · ${s.activeUnacknowledged} not acknowledged` : '',
    s.clearedUnacknowledged ? ` · ${s.clearedUnacknowledged} cleared, not acknowledged` : '',
    s.newest ? h('div', { class: 'sub' }, `Newest: ${s.newest.text}`) : null,
    h('a', { href: '/alarms', class: 'alarm-link' }, alarms.length ? 'Open the alarms' : 'Alarm history'));
});

function nodeEventText(e) {
  const who = `${e.bus} node ${e.node}`;
  switch (e.event) {
    case 'appeared': return `${who} appeared`;
    case 'identified': return `${who} identified as ${e.profile}${e.eds ? ` (${e.eds})` : ''}`;
    case 'identification_failed': return `${who} could not be identified: ${e.error}`;
    case 'nmt_changed': return `${who}: NMT ${NMT[e.from] || e.from} → ${NMT[e.nmt] || e.nmt}`;
    case 'offline': return `${who} went offline (${e.reason})`;
    case 'online': return `${who} is back online`;
    case 'heartbeat_written': return `${who}: heartbeat time written: ${e.heartbeat_ms} ms`;
    default: return `${who}: ${e.event}`;
  }
}

// Events lost on the way (the page fell behind): say so, and read
// everything again rather than show a state some event would have changed.
function lagged(message) {
  addEvent(Date.now(), `${message.lagged} ${message.topic} events were lost; reading every node again`, 'warn');
  loadAll();
}

stream.subscribe(['nodes'], (data, message) => {
  if (message.lagged) return lagged(message);
  if (data.event === 'bus_state') {
    const what = data.error_state ? data.error_state.replace('_', ' ') : data.state;
    addEvent(message.ts, `${data.bus}: CAN controller ${what} (TEC ${data.tx_error_counter}, REC ${data.rx_error_counter})${data.reason ? `: ${data.reason}` : ''}`,
      data.error_state === 'error_active' ? 'info' : 'warn');
    loadBuses();
    return;
  }
  addEvent(message.ts, nodeEventText(data), data.event === 'offline' ? 'warn' : 'info');
  refreshNode(data.bus, data.node);
});

const emcyText = (e) => `${e.bus} node ${e.node}${e.axis ? ` axis ${e.axis}` : ''}: EMCY ${e.code} ${e.text || ''}`;

stream.subscribe(['emcy'], (data, message) => {
  if (message.lagged) return lagged(message);
  addEvent(message.ts, emcyText(data), 'emcy');
  refreshNode(data.bus, data.node);
});

// ---- STOP ALL (the top bar's, stopall.js) ----------------------------------

document.addEventListener('candeck:stopped', () => {
  for (const entry of nodes.values()) refreshNode(entry.bus, entry.node.id);
});

// ---- scan ------------------------------------------------------------------
//
// Scan bus: the gateway probes node IDs 1 to 127 of each bus for their
// device type (POST /buses/{bus}/scan, an operator's), adds the nodes it
// finds and marks the silent ones offline; the table is read again.

const scanButton = $('#scan-bus');
const scanResult = $('#scan-result');

scanButton.addEventListener('click', async () => {
  const names = [...buses.keys()];
  scanResult.hidden = false;
  scanResult.dataset.state = 'busy';
  scanResult.textContent = `Scanning ${names.join(', ')}…`;
  const found = [];
  for (const name of names) {
    const done = await runAction(scanButton, 'Scanning…', () => api(`/buses/${encodeURIComponent(name)}/scan`, { method: 'POST', body: {} }));
    if (!done.ok) {
      scanResult.dataset.state = 'failed';
      scanResult.textContent = `Scan of ${name} failed (${clock()}): ${done.error.message}`;
      return;
    }
    const online = done.value.filter((n) => n.online !== false).length;
    found.push(`${name}: ${done.value.length} node${done.value.length === 1 ? '' : 's'}${online === done.value.length ? '' : `, ${online} online`}`);
  }
  scanResult.dataset.state = 'done';
  scanResult.textContent = `Scanned (${clock()}): ${found.join('; ')}.`;
  loadAll();
});

// ---- start and reconnect -------------------------------------------------

async function loadAll() {
  const list = await loadBuses();
  if (list) await Promise.all([loadNodes(list), loadMachines(list)]);
}

let live = false; // the stream is up: one "lost" event per outage

stream.onState(({ state, reconnected, error }) => {
  if (error) {
    problem('stream', `Live updates: ${error}`);
    return;
  }
  if (state === 'connected') {
    live = true;
    problem('stream', null);
    // Whatever happened while the page was away is read again.
    if (reconnected) {
      addEvent(Date.now(), 'Connection to the gateway is back', 'info');
      loadAll();
    }
    askAxisRate();
    pollBuses();
  } else if (state === 'disconnected') {
    clearTimeout(busTimer);
    if (live) addEvent(Date.now(), 'Connection to the gateway lost; reconnecting', 'warn');
    live = false;
  }
});

stream.connect();
loadAll();
loadHistory();
