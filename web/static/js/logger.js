// The data logger page (docs/data-logger.md): a channel picker that finds
// objects by name in a node's dictionary, the loggers with their
// statistics, and the chart of one logger, filled from its CSV and then
// live from the stream's loggers/{id} topic (rows numbered by `first`: a
// gap, rows the stream coalesced away, is filled from the CSV again).

import { api, runAction } from './api.js';
import { authorization } from './auth.js';
import { $, h, showMessage } from './dom.js';
import { stream } from './layout.js';
import { COLORS, LoggerChart } from './logchart.js';

const MAX_CHANNELS = 16;
const NUMERIC = new Set(['bool', 'i8', 'i16', 'i24', 'i32', 'i40', 'i48', 'i56', 'i64',
  'u8', 'u16', 'u24', 'u32', 'u40', 'u48', 'u56', 'u64', 'r32', 'r64']);

const pageMessage = $('#page-message');
const busSelect = $('#pick-bus');
const nodeSelect = $('#pick-node');
const search = $('#pick-search');
const results = $('#pick-results');
const chips = $('#channels');
const channelCount = $('#channel-count');
const loggerBody = $('#loggers tbody');
const chartPanel = $('#chart-panel');
const chartStatus = $('#chart-status');
const legend = $('#legend');
const chart = new LoggerChart($('#chart'), $('#readout'));

let channels = []; // {bus, node, index, sub, label}
let shown = null; // {id, next (rows held), unsubscribe, refetching}
let searchTimer = null;

const fail = (error) => showMessage(pageMessage, error.message || String(error));

// ---- the picker ------------------------------------------------------------

async function loadBuses() {
  const buses = await api('/buses');
  busSelect.replaceChildren(...buses.map((bus) => h('option', { value: bus.name }, bus.name)));
  await loadNodes();
}

async function loadNodes() {
  const bus = busSelect.value;
  if (!bus) return;
  const nodes = await api(`/buses/${encodeURIComponent(bus)}/nodes`);
  nodeSelect.replaceChildren(...nodes.map((node) => h('option', { value: String(node.id) },
    `${node.id}${node.name ? ` · ${node.name}` : ''}`)));
  findObjects();
}

async function findObjects() {
  const bus = busSelect.value;
  const node = nodeSelect.value;
  const text = search.value.trim();
  if (!bus || !node || !text) {
    results.replaceChildren();
    return;
  }
  let objects;
  try {
    objects = await api(`/buses/${encodeURIComponent(bus)}/nodes/${node}/od?q=${encodeURIComponent(text)}`);
  } catch (error) {
    results.replaceChildren(h('li', {}, error.message));
    return;
  }
  const found = [];
  for (const object of objects) {
    for (const sub of object.subs) {
      if (sub.access === 'wo' || !NUMERIC.has(sub.data_type)) continue;
      if (object.subs.length > 1 && sub.sub === 0) continue; // the count of entries
      found.push({ object, sub });
    }
  }
  results.replaceChildren(...found.slice(0, 40).map(({ object, sub }) => {
    const label = object.subs.length > 1 ? `${object.name}/${sub.name}` : object.name;
    return h('li', { dataset: { index: object.index, sub: String(sub.sub) } },
      h('span', {}, label, ' ', h('code', {}, `${object.index}:${sub.sub} ${sub.data_type}`)),
      h('button', { type: 'button', on: { click: () => addChannel({ bus, node: Number(node), index: object.index, sub: sub.sub, label: `${node}:${label}` }) } }, 'Add'));
  }));
  if (!found.length) results.replaceChildren(h('li', {}, 'No readable number matches.'));
}

function addChannel(channel) {
  if (channels.length >= MAX_CHANNELS) {
    showMessage(pageMessage, `a logger takes at most ${MAX_CHANNELS} channels`);
    return;
  }
  channels.push(channel);
  drawChips();
}

function drawChips() {
  chips.replaceChildren(...channels.map((channel, n) => h('li', { dataset: { index: channel.index, sub: String(channel.sub) } },
    `${channel.bus}/${channel.label}`,
    h('button', { type: 'button', 'aria-label': `Remove ${channel.label}`, on: { click: () => { channels.splice(n, 1); drawChips(); } } }, '×'))));
  channelCount.textContent = `${channels.length} of ${MAX_CHANNELS}`;
}

$('#new-logger').addEventListener('submit', async (event) => {
  event.preventDefault();
  showMessage(pageMessage, '');
  const body = {
    channels: channels.map(({ bus, node, index, sub }) => ({ bus, node, index, sub })),
    period_ms: Number($('#period').value),
    duration_s: Number($('#duration').value),
  };
  const done = await runAction($('#start'), 'Starting…', () => api('/loggers', { method: 'POST', body }));
  if (!done.ok) return fail(done.error);
  await loadLoggers();
  show(done.value);
});

// ---- the loggers -----------------------------------------------------------

let listTimer = null;

async function loadLoggers() {
  clearTimeout(listTimer);
  let list;
  try {
    list = await api('/loggers');
  } catch (error) {
    return fail(error);
  }
  if (!list.length) {
    loggerBody.replaceChildren(h('tr', { class: 'placeholder' }, h('td', { colspan: 7 }, 'No logger yet.')));
    return;
  }
  // The statistics of running loggers move: read them again in a second.
  if (list.some((logger) => logger.state === 'running')) listTimer = setTimeout(loadLoggers, 1000);
  loggerBody.replaceChildren(...list.slice().reverse().map((logger) => h('tr', { dataset: { id: String(logger.id), state: logger.state } },
    h('td', { 'data-label': 'Id' }, String(logger.id)),
    h('td', { 'data-label': 'State' }, logger.state),
    h('td', { 'data-label': 'Channels' }, logger.channels.map((c) => c.name).join(', ')),
    h('td', { 'data-label': 'Period' }, `${logger.period_ms} ms · ${logger.duration_s} s`),
    h('td', { 'data-label': 'Samples' }, String(logger.samples)),
    h('td', { 'data-label': 'Missed' }, String(logger.missed)),
    h('td', {},
      h('button', { type: 'button', class: 'show', on: { click: () => show(logger) } }, 'Chart'), ' ',
      h('button', { type: 'button', class: 'delete', on: { click: (event) => remove(event.target, logger.id) } }, 'Delete')))));
}

async function remove(button, id) {
  const done = await runAction(button, 'Deleting…', () => api(`/loggers/${id}`, { method: 'DELETE' }));
  if (!done.ok) return fail(done.error);
  if (shown && shown.id === id) hide();
  await loadLoggers();
}

// ---- the chart ---------------------------------------------------------------

async function csvText(id) {
  const response = await fetch(`/api/v1/loggers/${id}/data.csv`, { headers: authorization() });
  if (!response.ok) throw new Error(`the CSV of logger ${id}: HTTP ${response.status}`);
  return response.text();
}

/** The CSV's rows as the stream gives them: time_ms, then a value per
 * channel (the second column, time_utc, is for spreadsheets). */
function parseCsv(text) {
  const lines = text.trim().split('\n');
  return lines.slice(1).filter(Boolean).map((line) => line.split(',')
    .filter((_, n) => n !== 1)
    .map((cell) => (cell === '' ? null : Number(cell))));
}

function hide() {
  if (shown) shown.unsubscribe();
  shown = null;
  chartPanel.hidden = true;
}

async function refill() {
  if (!shown || shown.refetching) return;
  const current = shown;
  current.refetching = true;
  try {
    const rows = parseCsv(await csvText(current.id));
    if (shown !== current) return;
    chart.setChannels(current.names);
    chart.addRows(rows);
    current.next = current.base + rows.length;
  } catch (error) {
    fail(error);
  } finally {
    current.refetching = false;
  }
  // What came on the stream while the CSV was read: its rows may be newer
  // than the CSV's (a logger that then finished sends nothing after them).
  const held = current.held.splice(0);
  for (const data of held) if (shown === current) take(current, data);
}

/** One message of a logger's topic into the chart: its rows from the next
 * one the chart lacks, or the CSV again when the stream coalesced rows
 * away (`first` beyond the chart's end, with or without rows of its own:
 * a finished logger's last message may carry none). */
function take(current, data) {
  if (current.refetching) {
    current.held.push(data);
    return;
  }
  if (data.first > current.next) {
    refill();
    return;
  }
  const fresh = data.rows.slice(current.next - data.first);
  if (fresh.length) {
    chart.addRows(fresh);
    current.next += fresh.length;
  }
}

async function show(logger) {
  hide();
  chartPanel.hidden = false;
  $('#chart-title').textContent = `Logger ${logger.id}`;
  const names = logger.channels.map((c) => c.name);
  legend.replaceChildren(...names.map((name, n) => h('li', { style: `--swatch: ${COLORS[n % COLORS.length]}` }, name)));
  chart.setChannels(names);
  // The rows the gateway dropped from memory come before the CSV's first.
  const current = {
    id: logger.id, state: logger.state, names, base: logger.samples - logger.rows, next: 0,
    refetching: false, held: [], unsubscribe: () => {},
  };
  shown = current;
  current.unsubscribe = stream.subscribe([`loggers/${logger.id}`], (data) => {
    if (shown !== current) return;
    chartStatus.textContent = `${data.state} · ${data.samples} samples · ${data.missed} missed`;
    if (data.state !== current.state) {
      current.state = data.state;
      loadLoggers();
    }
    take(current, data);
  });
  chartStatus.textContent = `${logger.state} · ${logger.samples} samples · ${logger.missed} missed`;
  await refill();
}

$('#zoom-in').addEventListener('click', () => chart.zoom(0.5));
$('#zoom-out').addEventListener('click', () => chart.zoom(2));
$('#zoom-reset').addEventListener('click', () => chart.reset());
$('#download').addEventListener('click', async (event) => {
  if (!shown) return;
  const { id } = shown;
  const done = await runAction(event.target, 'CSV…', () => csvText(id));
  if (!done.ok) return fail(done.error);
  const url = URL.createObjectURL(new Blob([done.value], { type: 'text/csv' }));
  const link = h('a', { href: url, download: `logger-${id}.csv` });
  document.body.append(link);
  link.click();
  link.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10000);
});

busSelect.addEventListener('change', () => loadNodes().catch(fail));
nodeSelect.addEventListener('change', findObjects);
search.addEventListener('input', () => {
  clearTimeout(searchTimer);
  searchTimer = setTimeout(findObjects, 200);
});

stream.connect();
drawChips();
loadBuses().catch(fail);
loadLoggers();
