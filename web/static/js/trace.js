// The bus trace page (/buses/{bus}/trace): the bus's frames live from the
// stream topic buses/{bus}/frames, decoded by canopen.js, in a bounded
// table; filters by COB-ID, node and service; pause and clear; and the
// bus's recording (POST|GET|DELETE /buses/{bus}/recording) with its
// counters and the link to its candump log.
//
// Frames come in batches (the stream sends them at its rate, 10 a second
// by default); they are decoded as they come, and put on the page once per
// animation frame, so a busy bus costs one DOM update per screen refresh
// however many frames it carries, and a hidden tab costs none.

import { api, runAction } from './api.js';
import { $, h, showMessage } from './dom.js';
import { stream } from './layout.js';
import { SERVICES, SERVICE_NAMES, decodeFrame, idOf, inRanges, parseIdList, parseNodeList, sdoBlockTracker } from './canopen.js';

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

function entryOf(frame) {
  const decoded = decodeFrame(frame, blocks);
  return {
    ...decoded,
    time: timeText(frame.timestamp_us),
    dir: frame.dir,
    id: idOf(frame),
    idText: frame.id.replace(/^0x/, ''),
    dlc: frame.rtr ? `${frame.dlc} (RTR)` : String(frame.dlc),
    data: frame.data.replace(/(..)(?!$)/g, '$1 '),
  };
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
  kept.push(entry);
  pending.push(entry);
  // Trimmed by the thousand: one copy per thousand frames, not per frame.
  if (kept.length > MAX_KEPT + 1000) kept.splice(0, kept.length - MAX_KEPT);
  if (pending.length > MAX_KEPT + 1000) pending.splice(0, pending.length - MAX_KEPT);
  schedule();
}

// ---- rendering -----------------------------------------------------------

const rowTemplate = h('tr', {},
  ...['Time', 'Dir', 'COB-ID', 'Node', 'Service', 'Decoded', 'DLC', 'Data'].map((label) => h('td', { 'data-label': label })));
rowTemplate.cells[3].className = 'num';
rowTemplate.cells[6].className = 'num';

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
const topSpacer = h('tr', { class: 'spacer', 'aria-hidden': 'true' }, h('td', { colspan: 8 }));
const bottomSpacer = h('tr', { class: 'spacer', 'aria-hidden': 'true' }, h('td', { colspan: 8 }));

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
  showCounts();
}

scroller.addEventListener('scroll', schedule, { passive: true });

function showCounts() {
  counts.shown = shown.length;
  empty.hidden = counts.shown > 0;
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
  drawWindow(true);
  showCounts();
});

const servicesBox = $('#filter-services');
for (const service of SERVICES) {
  servicesBox.append(h('label', { class: `check svc-${service}` },
    h('input', { type: 'checkbox', name: 'service', value: service, checked: true }),
    ` ${SERVICE_NAMES[service]}`));
}

function readFilter() {
  const form = $('#filters');
  try {
    const ids = parseIdList($('#filter-ids').value);
    const nodes = parseNodeList($('#filter-nodes').value);
    const services = new Set([...form.querySelectorAll('input[name=service]:checked')].map((i) => i.value));
    filter = { ids, nodes, services };
    filterError.textContent = '';
    form.dataset.state = 'ok';
    followFilter();
  } catch (error) {
    filterError.textContent = error.message;
    form.dataset.state = 'invalid';
    return;
  }
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

// A test (or a curious person) may read what the page decoded.
window.candeckTrace = { counts, rows: () => shown };

followFilter();
showCounts();
stream.connect();
loadRecording();
