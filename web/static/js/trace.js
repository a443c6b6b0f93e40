// The bus trace page (/buses/{bus}/trace): the bus's frames live from the
// stream topic buses/{bus}/frames, decoded by canopen.js, in a bounded
// table; filters by COB-ID, node and service; pause and clear; and the
// bus's recording (POST|GET|DELETE /buses/{bus}/recording) with its
// counters and the link to its candump log.
//
// PDO frames are decoded by the node's current mapping (GET .../pdos and
// the data types of GET .../od, read once per node when its first PDO is
// seen, again when a frame's length no longer fits the mapping); every
// frame carries its delta time to the previous frame of its COB-ID, and
// the per-COB-ID view keeps one row per id (count, rate, last data, delta).
// The bus tools send on the bus: SYNC (bustools.js), a raw frame and an
// RPDO by its mapping with typed fields.
//
// Frames come in batches (the stream sends them at its rate, 10 a second
// by default); they are decoded as they come, and put on the page once per
// animation frame, so a busy bus costs one DOM update per screen refresh
// however many frames it carries, and a hidden tab costs none.

import { api, runAction } from './api.js';
import { $, h, showMessage } from './dom.js';
import { stream } from './layout.js';
import { SERVICES, SERVICE_NAMES, bytesOf, decodeFrame, idOf, inRanges, parseIdList, parseNodeList, sdoBlockTracker } from './canopen.js';
import { applyRefusal, sendRefusal, syncControl } from './bustools.js';

/** Rows the table shows at most (the newest). */
const MAX_ROWS = 2000;
/** Frames kept to show again when a filter changes. */
const MAX_KEPT = 10000;
const RECORDING_POLL_MS = 1000;

const pageEl = $('#trace-page');
const bus = pageEl.dataset.bus;
const busPath = `/buses/${encodeURIComponent(bus)}`;

const pageMessage = $('#page-message');
const tbody = $('#trace tbody');
const scroller = $('#trace-scroll');
const empty = $('#trace-empty');
const countsEl = $('#counts');
const pauseButton = $('#pause');
const filterError = $('#filter-error');
const recordButton = $('#record');
const recordingState = $('#recording-state');
const downloadLink = $('#download');

const kept = []; // decoded frames, oldest first, at most MAX_KEPT
let pending = []; // kept frames not yet on the page
let shown = []; // the table's rows: kept frames that pass the filter, at most MAX_ROWS
let scheduled = false;
let paused = false;
const counts = { received: 0, paused: 0, lost: 0, shown: 0 };
const blocks = sdoBlockTracker();
let filter = { ids: [], nodes: [], services: new Set(SERVICES) };

// ---- decoding and filtering ----------------------------------------------

const pad = (n, width = 2) => String(n).padStart(width, '0');

function timeText(us) {
  const ms = Math.floor(us / 1000);
  const d = new Date(ms);
  return `${pad(d.getHours())}:${pad(d.getMinutes())}:${pad(d.getSeconds())}.${pad(ms % 1000, 3)}`;
}

/** A delta time in µs as text: "10.000 ms", "2.500 s"; '' for none. */
export function deltaText(us) {
  if (us === null || us === undefined) return '';
  if (us < 1e6) return `${(us / 1000).toFixed(3)} ms`;
  return `${(us / 1e6).toFixed(3)} s`;
}

function entryOf(frame) {
  const decoded = decodeFrame(frame, blocks);
  const id = idOf(frame);
  const key = frame.extended ? `x${id}` : id;
  const before = lastSeen.get(key);
  lastSeen.set(key, frame.timestamp_us);
  const entry = {
    ...decoded,
    time: timeText(frame.timestamp_us),
    us: frame.timestamp_us,
    dir: frame.dir,
    id,
    idText: frame.id.replace(/^0x/, ''),
    dlc: frame.rtr ? `${frame.dlc} (RTR)` : String(frame.dlc),
    data: frame.data.replace(/(..)(?!$)/g, '$1 '),
    bytes: frame.rtr ? null : bytesOf(frame.data),
    key,
    deltaUs: before === undefined ? null : frame.timestamp_us - before,
  };
  if (entry.service === 'pdo' && entry.bytes && !frame.extended) pdoDetail(entry);
  return entry;
}

// ---- per COB-ID ----------------------------------------------------------

// Kept like the list: frames that come while paused are not counted.
const byId = new Map(); // key (id, or "x"+id for 29 bits) -> the id's row
const lastSeen = new Map(); // key -> time of its last frame, paused or not: the delta times

function countId(entry) {
  let stat = byId.get(entry.key);
  if (!stat) {
    stat = { key: entry.key, id: entry.id, idText: entry.idText, count: 0, firstUs: entry.us, lastUs: entry.us };
    byId.set(entry.key, stat);
  }
  stat.count += 1;
  stat.lastUs = entry.us;
  stat.deltaUs = entry.deltaUs;
  stat.last = entry;
}

/** Frames a second of an id, over the time since its first frame. */
function rateOf(stat) {
  const span = stat.lastUs - stat.firstUs;
  return stat.count > 1 && span > 0 ? ((stat.count - 1) * 1e6) / span : null;
}

// ---- PDOs by the node's mapping ------------------------------------------

const REMAP_RETRY_MS = 2000;
const nodePdos = new Map(); // node -> {state, at, byCob: Map cob -> {label, fields}}

function nodePath(node) {
  return `${busPath}/nodes/${node}`;
}

/** The node's PDOs and the data types of what they map: read once, kept. */
async function readNodePdos(node) {
  const [pdos, od] = await Promise.all([
    api(`${nodePath(node)}/pdos`),
    api(`${nodePath(node)}/od`).catch(() => []),
  ]);
  const types = new Map();
  for (const object of od) {
    for (const sub of object.subs || []) types.set(`${object.index.toLowerCase()}:${sub.sub}`, sub.data_type);
  }
  const fieldsOf = (pdo) => pdo.mapping.map((e) => ({
    index: e.index, sub: e.sub, bits: e.bits, name: e.name,
    type: types.get(`${e.index.toLowerCase()}:${e.sub}`) || null,
    dummy: parseInt(e.index, 16) <= 7,
  }));
  return { pdos, fieldsOf };
}

function loadNodePdos(node) {
  const known = nodePdos.get(node);
  if (known && (known.state === 'loading' || Date.now() - known.at < REMAP_RETRY_MS)) return;
  const record = { state: 'loading', at: Date.now(), byCob: known ? known.byCob : new Map() };
  nodePdos.set(node, record);
  readNodePdos(node).then(({ pdos, fieldsOf }) => {
    const byCob = new Map();
    for (const [kind, list] of [['TPDO', pdos.tpdo], ['RPDO', pdos.rpdo]]) {
      for (const pdo of list) {
        if (pdo.enabled) byCob.set(pdo.cob_id, { label: `${kind}${pdo.number}`, fields: fieldsOf(pdo) });
      }
    }
    Object.assign(record, { state: 'ready', at: Date.now(), byCob });
    // Frames already kept are decoded again with what was read.
    for (const entry of kept) if (entry.service === 'pdo' && entry.node === node && entry.bytes) pdoDetail(entry);
    redraw();
  }, () => Object.assign(record, { state: 'failed', at: Date.now() }));
}

/** One mapped value from the frame's bytes (little-endian, at `bit`). */
export function fieldValue(bytes, bit, field) {
  let raw = 0n;
  for (let i = field.bits - 1; i >= 0; i -= 1) {
    const at = bit + i;
    raw = (raw << 1n) | BigInt((bytes[at >> 3] >> (at & 7)) & 1);
  }
  const type = field.type || '';
  if (type === 'bool') return raw ? 'true' : 'false';
  if ((type === 'r32' || type === 'r64') && field.bits === Number(type.slice(1))) {
    const view = new DataView(new ArrayBuffer(8));
    if (field.bits === 32) {
      view.setUint32(0, Number(raw), true);
      return String(Number(view.getFloat32(0, true).toPrecision(7)));
    }
    view.setBigUint64(0, raw, true);
    return String(view.getFloat64(0, true));
  }
  if (type.startsWith('i') && field.bits > 0 && raw >> BigInt(field.bits - 1)) raw -= 1n << BigInt(field.bits);
  return raw.toString();
}

/** Sets a PDO entry's label and detail from its node's mapping, if known. */
function pdoDetail(entry) {
  const record = nodePdos.get(entry.node);
  if (!record) {
    loadNodePdos(entry.node);
    return;
  }
  const pdo = record.byCob.get(entry.id);
  if (!pdo) {
    if (record.state !== 'loading') loadNodePdos(entry.node);
    return;
  }
  const bits = pdo.fields.reduce((sum, f) => sum + f.bits, 0);
  if (Math.ceil(bits / 8) !== entry.bytes.length) {
    // Not the mapping's length: remapped since it was read (read again), or malformed.
    loadNodePdos(entry.node);
    entry.label = pdo.label;
    entry.detail = `${entry.bytes.length} bytes: the mapping read has ${bits} bits`;
    return;
  }
  let bit = 0;
  const parts = [];
  for (const field of pdo.fields) {
    if (!field.dummy) parts.push(`${field.name || `${field.index}:${field.sub}`}=${fieldValue(entry.bytes, bit, field)}`);
    bit += field.bits;
  }
  entry.label = pdo.label;
  entry.detail = parts.length ? parts.join(', ') : 'no objects mapped';
  entry.decodedBy = 'mapping';
}

/** A line that is no frame: the stream lost some, or went away. */
function gapOf(text) {
  return { gap: true, time: timeText(Date.now() * 1000), detail: text };
}

function passes(entry) {
  if (entry.gap) return true;
  if (!filter.services.has(entry.service)) return false;
  if (!inRanges(filter.ids, entry.id)) return false;
  if (filter.nodes.length && (entry.node === null || !inRanges(filter.nodes, entry.node))) return false;
  return true;
}

function keep(entry) {
  if (!entry.gap) countId(entry);
  kept.push(entry);
  pending.push(entry);
  // Trimmed by the thousand: one copy per thousand frames, not per frame.
  if (kept.length > MAX_KEPT + 1000) kept.splice(0, kept.length - MAX_KEPT);
  if (pending.length > MAX_KEPT + 1000) pending.splice(0, pending.length - MAX_KEPT);
  schedule();
}

// ---- rendering -----------------------------------------------------------

const rowTemplate = h('tr', {},
  ...['Time', 'Dir', 'COB-ID', 'Node', 'Service', 'Decoded', 'DLC', 'Data', 'Δt'].map((label) => h('td', { 'data-label': label })));
rowTemplate.cells[3].className = 'num';
rowTemplate.cells[6].className = 'num';
rowTemplate.cells[8].className = 'num delta';

function rowOf(entry) {
  const tr = rowTemplate.cloneNode(true);
  const c = tr.cells;
  c[0].textContent = entry.time;
  if (entry.gap) {
    tr.className = 'gap';
    c[5].textContent = entry.detail;
    return tr;
  }
  tr.dataset.service = entry.service;
  tr.dataset.id = entry.id;
  if (entry.node !== null) tr.dataset.node = entry.node;
  if (entry.malformed) tr.className = 'malformed';
  c[1].textContent = entry.dir;
  c[1].className = `dir ${entry.dir}`;
  c[2].textContent = entry.idText;
  c[3].textContent = entry.node === null ? '' : entry.node;
  c[4].textContent = entry.label;
  c[4].className = `svc ${entry.service}`;
  c[5].textContent = entry.detail;
  c[5].title = entry.detail;
  c[6].textContent = entry.dlc;
  c[7].textContent = entry.data;
  c[8].textContent = deltaText(entry.deltaUs);
  return tr;
}

function schedule() {
  if (scheduled) return;
  scheduled = true;
  requestAnimationFrame(render);
}

// The table holds only the rows in view (and a few either side) between
// two spacers as tall as the rows left out: 2000 rows cost a slice of an
// array, not 2000 rows the browser lays out again each time one comes.
let rowPx = 22; // measured from a row once drawn
const OVERSCAN = 12;
const topSpacer = h('tr', { class: 'spacer', 'aria-hidden': 'true' }, h('td', { colspan: 9 }));
const bottomSpacer = h('tr', { class: 'spacer', 'aria-hidden': 'true' }, h('td', { colspan: 9 }));

/** Whether the table is scrolled to its end (then it follows new rows). */
function atEnd() {
  return scroller.scrollHeight - scroller.scrollTop - scroller.clientHeight < rowPx * 2;
}

function render() {
  scheduled = false;
  const follow = atEnd();
  const fresh = pending.filter(passes);
  pending = [];
  for (const entry of fresh) shown.push(entry);
  const extra = shown.length - MAX_ROWS;
  if (extra > 0) {
    shown.splice(0, extra);
    // Reading older rows: they stay where they are on the screen.
    if (!follow) scroller.scrollTop = Math.max(0, scroller.scrollTop - extra * rowPx);
  }
  drawWindow(follow);
  drawIds();
  showCounts();
}

function drawWindow(follow) {
  const view = scroller.clientHeight;
  const top = follow ? Math.max(0, shown.length * rowPx - view) : scroller.scrollTop;
  const first = Math.max(0, Math.floor(top / rowPx) - OVERSCAN);
  const last = Math.min(shown.length, Math.ceil((top + view) / rowPx) + OVERSCAN);
  topSpacer.cells[0].style.height = `${first * rowPx}px`;
  bottomSpacer.cells[0].style.height = `${(shown.length - last) * rowPx}px`;
  const rows = shown.slice(first, last).map(rowOf);
  tbody.replaceChildren(topSpacer, ...rows, bottomSpacer);
  if (rows.length) {
    const measured = rows[0].getBoundingClientRect().height;
    if (measured > 0 && Math.abs(measured - rowPx) > 0.5) {
      rowPx = measured;
      drawWindow(follow);
      return;
    }
  }
  if (follow) scroller.scrollTop = scroller.scrollHeight;
}

/** Shows the kept frames again under the current filter. */
function redraw() {
  pending = [];
  shown = kept.filter(passes).slice(-MAX_ROWS);
  drawWindow(true);
  drawIds();
  showCounts();
}

scroller.addEventListener('scroll', schedule, { passive: true });

// The per-COB-ID view: one row per id that passes the filter.
const idsView = $('#ids-view');
const idsBody = $('#ids tbody');
const viewButton = $('#view-ids');
let byIdShown = false;

function drawIds() {
  if (!byIdShown) return;
  const stats = [...byId.values()].filter((s) => passes(s.last)).sort((a, b) => a.id - b.id);
  idsBody.replaceChildren(...stats.map((s) => {
    const rate = rateOf(s);
    return h('tr', { dataset: { id: s.id, service: s.last.service } },
      h('td', { 'data-label': 'COB-ID' }, s.idText),
      h('td', { class: 'num', 'data-label': 'Node' }, s.last.node === null ? '' : String(s.last.node)),
      h('td', { class: `svc ${s.last.service}`, 'data-label': 'Service' }, s.last.label),
      h('td', { class: 'num count', 'data-label': 'Count' }, s.count.toLocaleString()),
      h('td', { class: 'num rate', 'data-label': 'Rate' }, rate === null ? '' : `${rate.toFixed(1)}/s`),
      h('td', { class: 'num delta', 'data-label': 'Δt' }, deltaText(s.deltaUs)),
      h('td', { class: 'data', 'data-label': 'Last data' }, s.last.data),
      h('td', { class: 'detail', 'data-label': 'Decoded', title: s.last.detail }, s.last.detail));
  }));
  $('#ids-empty').hidden = stats.length > 0;
}

viewButton.addEventListener('click', () => {
  byIdShown = !byIdShown;
  viewButton.setAttribute('aria-pressed', String(byIdShown));
  idsView.hidden = !byIdShown;
  $('#trace-scroll').hidden = byIdShown;
  empty.hidden = byIdShown || counts.shown > 0;
  if (byIdShown) drawIds();
  else drawWindow(true);
});

function showCounts() {
  counts.shown = shown.length;
  empty.hidden = byIdShown || counts.shown > 0;
  const parts = [`${counts.shown.toLocaleString()} shown`, `${counts.received.toLocaleString()} received`];
  if (paused || counts.paused) parts.push(`${counts.paused.toLocaleString()} while paused`);
  if (counts.lost) parts.push(`${counts.lost.toLocaleString()} lost by the stream`);
  if (topic && topic.includes('?ids=')) parts.push('COB-IDs filtered by the gateway');
  countsEl.textContent = parts.join(' · ');
  countsEl.dataset.received = counts.received;
  countsEl.dataset.paused = counts.paused;
  countsEl.dataset.lost = counts.lost;
}

// ---- the stream ----------------------------------------------------------

function receive(data, message) {
  if (message.lagged) {
    // The page fell behind the bus: the server dropped these (never silently).
    counts.lost += message.lagged;
    keep(gapOf(`${message.lagged.toLocaleString()} frames lost: this page fell behind the bus`));
    return;
  }
  if (!Array.isArray(data)) return;
  counts.received += data.length;
  for (const frame of data) {
    // Decoded even while paused: the SDO block tracker must see every frame.
    const entry = entryOf(frame);
    if (paused) counts.paused += 1;
    else keep(entry);
  }
  if (paused) showCounts();
}

// A COB-ID filter of a few exact ids is also applied by the gateway
// (`?ids=`), so that a busy bus does not send this page what it would
// only throw away; ranges wider than that are filtered here alone.
const SERVER_IDS_MAX = 64;
let topic = null;
let unsubscribe = null;

function wantedTopic() {
  const base = `buses/${bus}/frames`;
  const total = filter.ids.reduce((sum, [low, high]) => sum + high - low + 1, 0);
  if (!filter.ids.length || total > SERVER_IDS_MAX) return base;
  const ids = [];
  for (const [low, high] of filter.ids) for (let id = low; id <= high; id += 1) ids.push(`0x${id.toString(16).toUpperCase()}`);
  return `${base}?ids=${ids.join(',')}`;
}

/** Subscribes to the frames topic the filter wants, if not already. */
function followFilter() {
  const wanted = wantedTopic();
  if (wanted === topic) return;
  // The old one goes first: frames in between are missed, never doubled.
  if (unsubscribe) unsubscribe();
  topic = wanted;
  unsubscribe = stream.subscribe([topic], receive);
  countsEl.dataset.topic = topic;
}

let wasLive = false;
stream.onState(({ state, error }) => {
  if (error) {
    problem('stream', `Live frames: ${error}`);
    return;
  }
  if (state === 'connected') {
    problem('stream', null);
    if (wasLive) loadRecording();
    wasLive = true;
  } else if (state === 'disconnected' && wasLive) {
    keep(gapOf('Connection to the gateway lost: frames missing until it is back'));
    wasLive = false;
  }
});

// ---- controls ------------------------------------------------------------

const problems = new Map();
function problem(key, text) {
  if (text) problems.set(key, text);
  else problems.delete(key);
  showMessage(pageMessage, [...problems.values()].join(' · '));
}

pauseButton.addEventListener('click', () => {
  paused = !paused;
  pauseButton.setAttribute('aria-pressed', String(paused));
  pauseButton.textContent = paused ? 'Resume' : 'Pause';
  if (!paused) counts.paused = 0;
  showCounts();
});

$('#clear').addEventListener('click', () => {
  kept.length = 0;
  pending = [];
  shown = [];
  counts.received = 0;
  counts.paused = 0;
  counts.lost = 0;
  byId.clear();
  lastSeen.clear();
  drawWindow(true);
  drawIds();
  showCounts();
});

const servicesBox = $('#filter-services');
for (const service of SERVICES) {
  servicesBox.append(h('label', { class: `check svc-${service}` },
    h('input', { type: 'checkbox', name: 'service', value: service, checked: true }),
    ` ${SERVICE_NAMES[service]}`));
}

/** Marks a field invalid (red) or valid. */
function markInvalid(input, bad) {
  if (bad) input.setAttribute('aria-invalid', 'true');
  else input.removeAttribute('aria-invalid');
}

/** A field's parsed value, or null with the field marked and its error said. */
function parsedField(input, parse, errors) {
  try {
    const value = parse(input.value);
    markInvalid(input, false);
    return value;
  } catch (error) {
    markInvalid(input, true);
    errors.push(error.message);
    return null;
  }
}

function readFilter() {
  const form = $('#filters');
  const errors = [];
  // Each field is read and marked on its own: a bad COB-ID marks its field, not the node field.
  const ids = parsedField($('#filter-ids'), parseIdList, errors);
  const nodes = parsedField($('#filter-nodes'), parseNodeList, errors);
  filterError.textContent = errors.join(' · ');
  if (errors.length) {
    form.dataset.state = 'invalid';
    return;
  }
  const services = new Set([...form.querySelectorAll('input[name=service]:checked')].map((i) => i.value));
  filter = { ids, nodes, services };
  form.dataset.state = 'ok';
  followFilter();
  redraw();
}

let filterTimer = null;
for (const event of ['input', 'change']) {
  $('#filters').addEventListener(event, () => {
    clearTimeout(filterTimer);
    filterTimer = setTimeout(readFilter, 150);
  });
}
$('#filters').addEventListener('submit', (event) => {
  event.preventDefault();
  clearTimeout(filterTimer);
  readFilter();
});

// ---- recording -----------------------------------------------------------

let recording = null;
let recordingTimer = null;

function bytesText(n) {
  if (n < 1024) return `${n} B`;
  if (n < 1024 * 1024) return `${(n / 1024).toFixed(1)} KB`;
  return `${(n / 1024 / 1024).toFixed(1)} MB`;
}

const STOP_REASONS = {
  asked: 'stopped', max_frames: 'stopped at its frame limit', max_seconds: 'stopped at its time limit',
  bus_closed: 'stopped: the bus closed', disk_error: 'stopped: writing the file failed',
};

function showRecording(status) {
  recording = status;
  const running = status.state === 'recording';
  recordButton.textContent = running ? 'Stop recording' : 'Record';
  recordButton.dataset.recording = String(running);
  recordingState.dataset.state = status.state;
  if (status.state === 'none') {
    recordingState.textContent = 'Not recorded since the gateway started.';
  } else {
    const end = status.stopped_us || Date.now() * 1000;
    const seconds = status.started_us ? Math.max(0, Math.round((end - status.started_us) / 1e6)) : 0;
    const parts = [
      running ? 'Recording' : (STOP_REASONS[status.stop_reason] || 'stopped').replace(/^./, (c) => c.toUpperCase()),
      `${status.frames.toLocaleString()} frames`, bytesText(status.bytes), `${seconds} s`,
    ];
    if (status.lost) parts.push(`${status.lost.toLocaleString()} missed`);
    recordingState.textContent = parts.join(' · ') + (status.error ? ` (${status.error})` : '');
  }
  recordingState.classList.toggle('warn', Boolean(status.lost || status.error));
  downloadLink.hidden = !status.download;
  if (status.download) {
    downloadLink.href = status.download;
    downloadLink.textContent = running ? 'Download so far' : `Download ${status.file || 'log'}`;
  }
  clearTimeout(recordingTimer);
  if (running) recordingTimer = setTimeout(loadRecording, RECORDING_POLL_MS);
}

async function loadRecording() {
  try {
    showRecording(await api(`${busPath}/recording`));
    problem('recording', null);
  } catch (error) {
    problem('recording', `Recording: ${error.message}`);
  }
}

recordButton.addEventListener('click', async () => {
  const running = recording && recording.state === 'recording';
  const result = await runAction(recordButton, running ? 'Stopping…' : 'Starting…',
    () => api(`${busPath}/recording`, { method: running ? 'DELETE' : 'POST', body: running ? undefined : {} }));
  if (result.ok) {
    problem('recording', null);
    showRecording(result.value);
  } else {
    problem('recording', `Recording: ${result.error.message}`);
    loadRecording();
  }
});

// ---- bus tools -----------------------------------------------------------

const sync = syncControl(bus);
$('#sync-slot').replaceWith(sync.element);

const rawForm = $('#raw-form');
const rawResult = $('#raw-result');
rawForm.addEventListener('submit', async (event) => {
  event.preventDefault();
  const idInput = $('#raw-id');
  const dataInput = $('#raw-data');
  const digits = idInput.value.trim().replace(/^0x/i, '').replace(/h$/i, '');
  const data = dataInput.value.replace(/\s+/g, '');
  const idOk = /^[0-9a-f]{1,8}$/i.test(digits) && parseInt(digits, 16) <= 0x1fffffff;
  const dataOk = /^([0-9a-f]{2}){0,8}$/i.test(data);
  markInvalid(idInput, !idOk);
  markInvalid(dataInput, !dataOk);
  rawResult.dataset.state = 'failed';
  if (!idOk) return void (rawResult.textContent = `'${idInput.value}' is no hex CAN identifier (0 to 7FF, or to 1FFFFFFF)`);
  if (!dataOk) return void (rawResult.textContent = 'Data: 0 to 8 bytes, two hex digits each');
  const id = parseInt(digits, 16);
  const body = { id: `0x${id.toString(16).toUpperCase()}`, data, extended: id > 0x7ff };
  const result = await runAction($('#raw-send'), 'Sending…', () => api(`${busPath}/frames`, { method: 'POST', body }));
  rawResult.dataset.state = result.ok ? 'done' : 'failed';
  rawResult.textContent = result.ok
    ? `Sent ${result.value.id} [${result.value.dlc}] ${result.value.data || '(no data)'}`
    : `Not sent: ${result.error.message}`;
});

const rpdoForm = $('#rpdo-form');
const rpdoFields = $('#rpdo-fields');
const rpdoResult = $('#rpdo-result');
const rpdoSend = $('#rpdo-send');
let rpdoTarget = null; // {node, number, fields}

/** The range of an integer field of `bits` bits, signed or not. */
function intRange(field) {
  const bits = BigInt(field.bits);
  return field.type && field.type.startsWith('i')
    ? [-(1n << (bits - 1n)), (1n << (bits - 1n)) - 1n]
    : [0n, (1n << bits) - 1n];
}

function rpdoInput(field, i) {
  const name = field.name || `${field.index}:${field.sub}`;
  const id = `rpdo-field-${i}`;
  const real = field.type === 'r32' || field.type === 'r64';
  const input = field.type === 'bool'
    ? h('input', { id, type: 'checkbox', dataset: { key: name, kind: 'bool' } })
    : h('input', {
      id, type: 'text', inputmode: real ? 'decimal' : 'numeric', value: '0', spellcheck: 'false', required: true,
      dataset: { key: name, kind: real ? 'real' : 'int' },
    });
  const type = field.type ? `${field.type}` : `${field.bits} bits`;
  return h('label', { class: 'rpdo-field' }, `${name} `, h('span', { class: 'unit' }, `(${type})`), ' ', input);
}

$('#rpdo-load').addEventListener('click', async () => {
  const node = Number($('#rpdo-node').value);
  const number = Number($('#rpdo-number').value);
  rpdoTarget = null;
  rpdoSend.disabled = true;
  rpdoFields.replaceChildren();
  rpdoResult.dataset.state = 'failed';
  if (!Number.isInteger(node) || node < 1 || node > 127) return void (rpdoResult.textContent = 'Node: 1 to 127');
  if (!Number.isInteger(number) || number < 1 || number > 512) return void (rpdoResult.textContent = 'RPDO: 1 to 512');
  const result = await runAction($('#rpdo-load'), 'Reading…', () => readNodePdos(node));
  if (!result.ok) return void (rpdoResult.textContent = `Node ${node}: ${result.error.message}`);
  const pdo = result.value.pdos.rpdo.find((p) => p.number === number);
  if (!pdo) return void (rpdoResult.textContent = `Node ${node} has no RPDO ${number}`);
  if (!pdo.enabled) return void (rpdoResult.textContent = `RPDO ${number} of node ${node} is disabled: enable it on the PDO page`);
  const fields = result.value.fieldsOf(pdo).filter((f) => !f.dummy);
  if (!fields.length) return void (rpdoResult.textContent = `RPDO ${number} of node ${node} maps nothing`);
  rpdoTarget = { node, number, fields };
  rpdoFields.replaceChildren(...fields.map(rpdoInput));
  rpdoResult.dataset.state = '';
  rpdoResult.textContent = `RPDO ${number} on COB-ID ${pdo.cob_id.toString(16).toUpperCase()}`;
  rpdoSend.disabled = Boolean(sendBlocked);
});

/** The RPDO's values from its fields, or null with the bad ones marked. */
function rpdoValues() {
  const values = {};
  const bad = [];
  rpdoTarget.fields.forEach((field, i) => {
    const input = $(`#rpdo-field-${i}`);
    let ok = true;
    if (input.dataset.kind === 'bool') values[input.dataset.key] = input.checked;
    else if (input.dataset.kind === 'real') {
      const value = Number(input.value.trim());
      ok = input.value.trim() !== '' && Number.isFinite(value);
      if (ok) values[input.dataset.key] = value;
      else bad.push(`${input.dataset.key}: '${input.value}' is no number`);
    } else {
      const text = input.value.trim();
      ok = /^-?\d+$/.test(text) || /^0x[0-9a-f]+$/i.test(text);
      const [low, high] = intRange(field);
      if (ok) {
        const value = BigInt(text);
        ok = value >= low && value <= high;
        if (ok) values[input.dataset.key] = Number(value);
        else bad.push(`${input.dataset.key}: ${text} is outside ${low} to ${high}`);
      } else bad.push(`${input.dataset.key}: '${text}' is no whole number`);
    }
    markInvalid(input, !ok);
  });
  if (bad.length) {
    rpdoResult.dataset.state = 'failed';
    rpdoResult.textContent = bad.join(' · ');
    return null;
  }
  return values;
}

rpdoForm.addEventListener('submit', async (event) => {
  event.preventDefault();
  if (!rpdoTarget) return;
  const values = rpdoValues();
  if (!values) return;
  const { node, number } = rpdoTarget;
  const result = await runAction(rpdoSend, 'Sending…',
    () => api(`${nodePath(node)}/pdos/rpdo/${number}/send`, { method: 'POST', body: { values } }));
  rpdoResult.dataset.state = result.ok ? 'done' : 'failed';
  rpdoResult.textContent = result.ok
    ? `Sent on ${result.value.cob_id.toString(16).toUpperCase()}: ${result.value.data || '(no data)'}`
    : `Not sent: ${result.error.message}`;
});

let sendBlocked = '';
sendRefusal().then((reason) => {
  sendBlocked = reason;
  const controls = [...rawForm.querySelectorAll('input, button'), ...rpdoForm.querySelectorAll('input, button')];
  applyRefusal(reason, controls, $('#send-refusal'));
  if (!reason) rpdoSend.disabled = !rpdoTarget;
});

// A test (or a curious person) may read what the page decoded.
window.candeckTrace = { counts, rows: () => shown, ids: () => [...byId.values()].map((s) => ({ ...s, last: undefined, rate: rateOf(s) })) };

followFilter();
showCounts();
stream.connect();
loadRecording();
