// One node's page: identity, NMT commands, store/restore, the DCF backup
// and the object-dictionary browser. What it shows of the device is what
// the gateway read from it: the identity is read again over REST whenever
// the stream says the node changed, and a value in the dictionary is the
// one an SDO read (or the read-back after a write) returned, never what
// the page sent.

import { api, apiFetch, ApiError, describeError, runAction } from './api.js';
import { authorization, signInAgain, whenSignedIn } from './auth.js';
import { $, clock, h, showMessage, updateRows } from './dom.js';
import { stream } from './layout.js';

const root = $('#node-page');
const bus = root.dataset.bus;
const nodeId = root.dataset.node;
const base = `/buses/${encodeURIComponent(bus)}/nodes/${encodeURIComponent(nodeId)}`;

const pageMessage = $('#page-message');
const body = $('#node-body');
const title = $('#node-title');
const links = $('#node-links');
const identity = $('#identity');
const nmtResult = $('#nmt-result');
const configResult = $('#config-result');
const odRoot = $('#od');
const odCount = $('#od-count');
const search = $('#od-search');
const hexToggle = $('#od-hex');

const DRIVES = new Set(['umc', 'jmc_stepper', 'cia402']);
const NMT = {
  boot_up: 'boot-up', pre_operational: 'pre-operational', operational: 'operational',
  stopped: 'stopped', unknown: 'unknown',
};
const COMMANDS = {
  start: 'Start', stop: 'Stop', pre_operational: 'Pre-operational',
  reset_node: 'Reset node', reset_communication: 'Reset communication',
};

let detail = null; // GET .../nodes/{id}, as last read
let detailReadAt = 0; // Date.now() of that read
let pendingNmt = null; // {command, at}: the page waits for the state it asked for

const hex = (n, digits) => `0x${Number(n).toString(16).toUpperCase().padStart(digits, '0')}`;

// ---- confirmation ----------------------------------------------------------

/** Asks in a modal dialog; resolves true when confirmed. */
function confirmAction(text, okLabel) {
  const dialog = $('#confirm');
  $('#confirm-text').textContent = text;
  $('#confirm-ok').textContent = okLabel;
  dialog.returnValue = '';
  return new Promise((resolve) => {
    dialog.addEventListener('close', () => resolve(dialog.returnValue === 'ok'), { once: true });
    dialog.showModal();
  });
}

/** An API error as elements: an SDO abort as its code and CiA 301 text. */
function errorView(error) {
  const detailBody = error instanceof ApiError ? error.body?.error : error;
  if (detailBody && detailBody.abort_code) {
    return h('span', { class: 'abort' }, 'The device refused: ',
      h('code', { class: 'abort-code' }, detailBody.abort_code), ' ',
      h('span', { class: 'abort-text' }, detailBody.abort_text || detailBody.message || ''));
  }
  if (error instanceof Error) return h('span', {}, error.message);
  return h('span', {}, describeError(0, { error: detailBody }, 'failed'));
}

function result(el, state, ...children) {
  el.dataset.state = state;
  el.replaceChildren(...children.flat().filter((c) => c !== null && c !== undefined && c !== false && c !== ''));
}

// ---- identity --------------------------------------------------------------

function fact(label, value, key) {
  return [h('dt', {}, label), h('dd', { dataset: { fact: key } }, value)];
}

// How old the gateway's last frame of the node is: its `last_seen_ms` as
// last read. The reads come every SEEN_POLL_MS; the time since the read
// counts only once they stop coming (the gateway unreachable), else a
// node heard every 500 ms read 1.9 s ago would be 1.9 s old, and marked
// stale, while the gateway says 40 ms (issue 31 point 6).
function seenAgeMs() {
  const sinceRead = Date.now() - detailReadAt;
  return Math.max(0, detail.last_seen_ms + (sinceRead > 2 * SEEN_POLL_MS ? sinceRead : 0));
}

function lastSeen() {
  if (!detail) return '…';
  const seconds = seenAgeMs() / 1000;
  return seconds < 1 ? 'just now' : `${seconds.toFixed(0)} s ago`;
}

function heartbeatText(d) {
  return d.heartbeat_ms ? `every ${d.heartbeat_ms} ms` : h('span', { class: 'sub' }, 'none heard');
}

function renderIdentity() {
  const d = detail;
  const id = d.identity;
  const type = d.device_type;
  title.textContent = d.name ? `${d.name}` : `Node ${d.id}`;
  document.title = `${d.name || `Node ${d.id}`} · node ${d.id} · ${bus} · candeck`;
  const emcy = d.emcy || [];
  identity.replaceChildren(
    ...fact('Name', d.name || h('span', { class: 'sub' }, 'no name'), 'name'),
    ...fact('Vendor', id ? hex(id.vendor_id, 8) : '…', 'vendor'),
    ...fact('Product', id ? hex(id.product_code, 8) : '…', 'product'),
    ...fact('Revision', id ? hex(id.revision, 8) : '…', 'revision'),
    ...fact('Serial', id ? hex(id.serial, 8) : '…', 'serial'),
    ...fact('Device type', type === null || type === undefined ? '…'
      : `${hex(type, 8)} (profile ${type & 0xffff}${type >>> 16 ? `, additional ${hex(type >>> 16, 4)}` : ''})`, 'device-type'),
    ...fact('Profile', d.profile || '…', 'profile'),
    ...fact('EDS', d.eds || h('span', { class: 'sub' }, 'none matched'), 'eds'),
    ...fact('NMT state', h('span', { class: `nmt nmt-${d.nmt}` }, NMT[d.nmt] || d.nmt), 'nmt'),
    ...fact('Online', h('span', { class: `badge ${d.online ? 'ok' : 'bad'}` }, d.online ? 'online' : 'offline'), 'online'),
    ...fact('Last seen', h('span', { id: 'last-seen' }, lastSeen()), 'last-seen'),
    ...fact('Heartbeat', heartbeatText(d), 'heartbeat'),
    ...fact('Last EMCY', emcy.length
      ? h('span', { class: 'emcy' }, h('code', {}, emcy[emcy.length - 1].code), ' ', emcy[emcy.length - 1].text)
      : h('span', { class: 'sub' }, 'none'), 'emcy'),
  );
  renderLinks();
  renderEds();
  if (pendingNmt) showNmtState();
}

// ---- EDS assignment ------------------------------------------------------

const edsCurrent = $('#eds-current');
const edsSelect = $('#eds-file');
const edsResult = $('#eds-result');
let edsFiles = null; // names of the catalog's usable files
let edsCatalog = new Map(); // name -> the catalog's entry (its identity)
const edsWarning = $('#eds-warning');

/** Why `file` does not describe this node, by identity (vendor, product),
 * or '' (issue 31 point 6: a product 0xA16 file went onto a 0x401 device
 * with no word). */
function identityMismatch(file) {
  const entry = edsCatalog.get(file);
  const id = detail?.identity;
  if (!entry || !id) return '';
  const differs = [];
  if (entry.vendor_id !== null && entry.vendor_id !== id.vendor_id) differs.push(`vendor ${hex(entry.vendor_id, 8)}, the device ${hex(id.vendor_id, 8)}`);
  if (entry.product_code !== null && entry.product_code !== id.product_code) differs.push(`product ${hex(entry.product_code, 8)}, the device ${hex(id.product_code, 8)}`);
  const product = productOf(entry);
  return differs.length ? `${file} describes another device${product ? ` (${product})` : ''}: ${differs.join('; ')}.` : '';
}

/** A catalog entry's product and vendor names, as its [DeviceInfo] gives them. */
function productOf(entry) {
  return [entry.product_name, entry.vendor_name].filter(Boolean).join(', ');
}

function showEdsWarning() {
  const text = edsSelect.value ? identityMismatch(edsSelect.value) : '';
  edsWarning.textContent = text;
  edsWarning.hidden = !text;
}

function renderEds() {
  const d = detail;
  edsCurrent.textContent = d.eds
    ? `Described by ${d.eds}, ${d.eds_assigned ? 'assigned by hand' : 'matched by its identity'}.`
    : 'No EDS describes this node: none matches its identity. Assign one.';
  edsCurrent.dataset.assigned = String(Boolean(d.eds_assigned));
  $('#eds-unassign').disabled = !d.eds_assigned;
  if (edsFiles && d.eds && edsFiles.includes(d.eds)) edsSelect.value = d.eds;
  showEdsWarning();
}

async function loadEdsFiles() {
  try {
    const list = await api('/eds');
    const usable = list.files.filter((f) => f.usable);
    edsFiles = usable.map((f) => f.name);
    edsCatalog = new Map(usable.map((f) => [f.name, f]));
    edsSelect.replaceChildren(...usable.map((f) => h('option', { value: f.name },
      f.product_name ? `${f.name} (${f.product_name})` : f.name)));
    if (detail) renderEds();
  } catch (error) {
    result(edsResult, 'failed', `The EDS files: ${error.message}`);
  }
}

async function assignEds(button, file) {
  const mismatch = file ? identityMismatch(file) : '';
  if (mismatch && !(await confirmAction(`${mismatch} Assign it to node ${nodeId} anyway? Its objects may not be the device's.`, 'Assign anyway'))) return;
  const request = file
    ? api(`${base}/eds`, { method: 'PUT', body: { file } })
    : api(`${base}/eds`, { method: 'DELETE' });
  const done = await runAction(button, file ? 'Assigning…' : 'Unassigning…', () => request);
  if (!done.ok) {
    result(edsResult, 'failed', h('strong', {}, `Not changed (${clock()}): `), errorView(done.error));
    return;
  }
  result(edsResult, 'done', h('strong', {}, file ? `${file} assigned (${clock()}).` : `Matched by identity again (${clock()}).`));
  await loadDetail();
  loadDictionary();
  checkProgramSupport();
}

edsSelect.addEventListener('change', showEdsWarning);
$('#eds-assign').addEventListener('click', (event) => assignEds(event.currentTarget, edsSelect.value));
$('#eds-unassign').addEventListener('click', (event) => assignEds(event.currentTarget, null));
loadEdsFiles();

function renderLinks() {
  const d = detail;
  const items = [];
  const path = `/nodes/${encodeURIComponent(bus)}/${encodeURIComponent(nodeId)}`;
  if (DRIVES.has(d.profile)) {
    for (const axis of d.axes || []) {
      items.push(h('a', { href: `${path}/axes/${axis.axis}`, class: 'pill' }, `Drive axis ${axis.axis}`));
    }
  }
  if (d.profile === 'uioled') items.push(h('a', { href: `${path}/leds`, class: 'pill' }, 'LEDs'));
  if (d.profile === 'cia401') items.push(h('a', { href: `${path}/io`, class: 'pill', id: 'io-link' }, 'I/O'));
  items.push(h('a', { href: `${path}/pdos`, class: 'pill' }, 'PDOs'));
  // The node is read again at each of its events: a link that stays the
  // same stays the same element (one replaced between touch and release
  // loses the tap).
  for (const a of items) a.dataset.key = a.getAttribute('href');
  updateRows(links, items);
}

let reading = false;
let readAgain = false;
// The device left this ID for another (a node-ID change): the gateway
// forgets the ID, so the page reads it no more; the change's result links
// to the new one.
let moved = false;
// The node ID it moved to, where this page changed it (the stream's
// `offline` event does not say).
let movedTo = null;

/** The device left this node ID: the page stops saying what it last read
 * (operational, online) and says where it went, or that it is gone. */
function showMoved() {
  moved = true;
  const state = movedTo === null ? 'moved to another node ID' : `moved to node ID ${movedTo}`;
  for (const key of ['nmt', 'online']) {
    const dd = identity.querySelector(`dd[data-fact="${key}"]`);
    if (dd) dd.replaceChildren(h('span', { class: 'badge bad' }, key === 'online' ? 'gone' : state));
  }
  const seen = identity.querySelector('dd[data-fact="last-seen"]');
  if (seen) seen.replaceChildren(h('span', { class: 'sub' }, 'not on this node ID any more'));
  pageMessage.dataset.kind = 'error';
  pageMessage.hidden = false;
  pageMessage.dataset.moved = 'true';
  pageMessage.replaceChildren(`Node ${nodeId} ${state}: this ID is no longer on the bus. `,
    movedTo === null ? '' : h('a', { href: `/nodes/${encodeURIComponent(bus)}/${movedTo}` }, `Open node ${movedTo}`));
}

/** Reads the node again; one read at a time, a read asked meanwhile runs after. */
async function loadDetail() {
  if (moved) return;
  if (reading) {
    readAgain = true;
    return;
  }
  reading = true;
  try {
    const fresh = await api(base);
    // Moved while it was read: what it read is no longer this ID's.
    if (moved) return;
    const first = !detail;
    detail = fresh;
    detailReadAt = Date.now();
    showMessage(pageMessage, '');
    body.hidden = false;
    renderIdentity();
    showNodeIdPanel();
    if (first) {
      loadDictionary();
      checkProgramSupport();
    }
  } catch (error) {
    if (error.status === 404 || error.status === 400) {
      // Unknown bus or node, or a path that names none: the page has
      // nothing to show but why.
      detail = null;
      body.hidden = true;
      title.textContent = error.code === 'unknown_bus' ? 'Unknown bus' : 'Unknown node';
      links.replaceChildren(h('a', { href: '/', class: 'pill' }, 'Back to the overview'));
      showMessage(pageMessage, error.message);
    } else {
      showMessage(pageMessage, `Node: ${error.message}`);
    }
  } finally {
    reading = false;
  }
  if (readAgain) {
    readAgain = false;
    loadDetail();
  }
}

// "Last seen" and the heartbeat the gateway hears change with every frame
// of the node: read again from the node list (no SDO, unlike the node's
// own answer) every few seconds, so that the age shown is the gateway's,
// not the time since the page last read the node (issue 21 point 5).
const SEEN_POLL_MS = 2000;
let seenPolling = false;

async function pollSeen() {
  if (!detail || seenPolling || stream.state !== 'connected') return;
  seenPolling = true;
  try {
    const list = await api(`/buses/${encodeURIComponent(bus)}/nodes`);
    const me = list.find((n) => n.id === detail.id);
    if (me && detail) {
      detail.last_seen_ms = me.last_seen_ms;
      detail.heartbeat_ms = me.heartbeat_ms;
      detail.online = me.online;
      detailReadAt = Date.now();
      const heartbeat = document.querySelector('dd[data-fact="heartbeat"]');
      if (heartbeat) heartbeat.replaceChildren(heartbeatText(detail));
    }
  } catch {
    // The next poll tries again; the age keeps counting meanwhile.
  } finally {
    seenPolling = false;
  }
}

setInterval(pollSeen, SEEN_POLL_MS);

setInterval(() => {
  const el = document.getElementById('last-seen');
  if (!el) return;
  el.textContent = lastSeen();
  // Older than one and a half heartbeat periods (or 5 s without one): stale.
  const age = detail ? seenAgeMs() : 0;
  el.dataset.ageMs = String(Math.round(age));
  el.classList.toggle('stale', Boolean(detail) && age > Math.max(1.5 * (detail.heartbeat_ms || 0), detail.heartbeat_ms ? 0 : 5000));
}, 1000);

// ---- NMT -------------------------------------------------------------------

function showNmtState() {
  const { command, at } = pendingNmt;
  // NMT commands are unconfirmed: the state is what the gateway heard
  // from the node afterwards. A node with no heartbeat tells it only at
  // its next boot-up, and the page says so rather than guess.
  const silent = !detail.heartbeat_ms && command !== 'reset_node' && command !== 'reset_communication';
  result(nmtResult, 'done', h('strong', {}, `${COMMANDS[command]} sent (${at}). `),
    `NMT state the gateway knows: ${NMT[detail.nmt] || detail.nmt}${detail.online ? '' : ', offline'}.`,
    silent ? h('div', { class: 'sub' }, 'This node sends no heartbeat (0x1017 is 0): the gateway learns its NMT state only from its next boot-up.') : null);
}

for (const button of document.querySelectorAll('#nmt-buttons button')) {
  button.addEventListener('click', async () => {
    const { command } = button.dataset;
    if (button.dataset.confirm && !(await confirmAction(button.dataset.confirm, COMMANDS[command]))) return;
    result(nmtResult, 'busy', `Sending ${COMMANDS[command]}…`);
    const sent = await runAction(button, 'Sending…', () => api(`${base}/nmt`, { method: 'POST', body: { command } }));
    if (!sent.ok) {
      pendingNmt = null;
      result(nmtResult, 'failed', h('strong', {}, `${COMMANDS[command]} failed: `), errorView(sent.error));
      return;
    }
    pendingNmt = { command, at: clock() };
    result(nmtResult, 'busy', h('strong', {}, `${COMMANDS[command]} sent (${pendingNmt.at}). `), 'Waiting for the node…');
    // NMT is unconfirmed: the state shown is the one the gateway hears
    // next (heartbeat, boot-up), read when the stream says it changed,
    // and once more in case it did not change.
    setTimeout(loadDetail, 1500);
  });
}

// ---- node ID (UniSwarm 0x2040, LSS, or the JMC's switches) ----------------

// The products that change their node ID by 0x2040, save and reset.
const NODE_ID_PROFILES = new Set(['umc', 'uioled']);
const nodeIdResult = $('#node-id-result');

// What the panel says for each way a node's ID changes.
const NODE_ID_HOW = {
  object: 'Writes it to 0x2040 sub 1, stores the manufacturer parameters and resets the node: it boots up under the new ID (UniSwarm UMC and UIO1LED).',
  lss: 'By LSS (CiA 305): the device is selected by its identity (0x1018), given the new ID, stores it and is reset: it boots up under the new ID. Needs a device that answers LSS.',
  switches: 'This drive takes its node ID from its rotary switches S1 (low four bits) and S3 (high three bits), read at power-on: set them on the device. It has no node-ID object and no LSS.',
  no_identity: 'LSS selects a device by its whole identity (0x1018 subs 1 to 4), and this node has not given all of it: its node ID cannot be changed from here.',
};

/** How this node's ID can be changed, or null while it is not known. */
function nodeIdWay() {
  if (!detail) return null;
  if (NODE_ID_PROFILES.has(detail.profile)) return 'object';
  if (detail.profile === 'jmc_stepper') return 'switches';
  const id = detail.identity;
  const whole = id && id.product_code != null && id.revision != null && id.serial != null;
  return whole ? 'lss' : 'no_identity';
}

function showNodeIdPanel() {
  const way = nodeIdWay();
  $('#node-id-panel').hidden = way === null;
  $('#node-id-panel').dataset.way = way || '';
  $('#node-id-form').hidden = way !== 'object' && way !== 'lss';
  $('#node-id-how').textContent = NODE_ID_HOW[way] || '';
}

/** The request that gives this node `newId` the way its product takes one. */
function changeNodeId(way, newId) {
  if (way === 'lss') {
    const { vendor_id, product_code, revision, serial } = detail.identity;
    return api(`/buses/${encodeURIComponent(bus)}/lss/configure`, {
      method: 'POST', body: { vendor_id, product_code, revision, serial, node_id: newId, store: true },
    });
  }
  return api(`${base}/node-id`, { method: 'POST', body: { node_id: newId } });
}

$('#node-id-form').addEventListener('submit', async (event) => {
  event.preventDefault();
  const way = nodeIdWay();
  if (way !== 'object' && way !== 'lss') return;
  const button = $('#node-id-change');
  const newId = Number($('#node-id-new').value);
  if (!(await confirmAction(`Change node ${nodeId} to node ID ${newId}? The device stores it and restarts: its drives stop and unsaved parameters are lost.`, 'Change node ID'))) return;
  result(nodeIdResult, 'busy', `Changing to node ID ${newId}${way === 'lss' ? ' by LSS' : ''}…`);
  const done = await runAction(button, 'Changing…', () => changeNodeId(way, newId));
  if (!done.ok) {
    result(nodeIdResult, 'failed', h('strong', {}, `Change failed (${clock()}): `), errorView(done.error));
    return;
  }
  movedTo = done.value.id;
  if (moved) showMoved();
  const href = `/nodes/${encodeURIComponent(bus)}/${done.value.id}`;
  result(nodeIdResult, 'done', h('strong', {}, `The device booted up as node ${done.value.id} (${clock()}). `),
    h('a', { href, id: 'node-id-new-page' }, `Open node ${done.value.id}`));
});

// ---- store, restore, DCF ---------------------------------------------------

const whatSelect = $('#config-what');
const sourceSelect = $('#restore-source');

$('#store').addEventListener('click', async (event) => {
  const button = event.currentTarget;
  const what = whatSelect.value;
  if (!(await confirmAction(`Store ${what} parameters of node ${nodeId} in the device's memory? They replace what it saved before.`, 'Store'))) return;
  result(configResult, 'busy', `Storing ${what} parameters…`);
  const done = await runAction(button, 'Storing…', () => api(`${base}/store`, { method: 'POST', body: { what } }));
  if (!done.ok) {
    result(configResult, 'failed', h('strong', {}, `Store failed (${clock()}): `), errorView(done.error));
    return;
  }
  const v = done.value;
  result(configResult, 'done', h('strong', {}, `Stored ${v.what} parameters (${clock()}). `),
    `The device accepted "${v.signature}" in ${v.index}:${v.sub}${v.name ? ` (${v.name})` : ''}.`);
});

$('#restore').addEventListener('click', async (event) => {
  const button = event.currentTarget;
  const what = whatSelect.value;
  const source = sourceSelect.value;
  const from = source === 'saved' ? 'the values last stored' : 'the factory defaults';
  if (!(await confirmAction(`Restore ${what} parameters of node ${nodeId} from ${from}? The device takes them at its next reset.`, 'Restore'))) return;
  result(configResult, 'busy', `Restoring ${what} parameters from ${from}…`);
  const done = await runAction(button, 'Restoring…', () => api(`${base}/restore`, { method: 'POST', body: { what, source } }));
  if (!done.ok) {
    result(configResult, 'failed', h('strong', {}, `Restore failed (${clock()}): `), errorView(done.error));
    return;
  }
  const v = done.value;
  result(configResult, 'done', h('strong', {}, `Restore of ${v.what} parameters from ${from} accepted (${clock()}). `),
    `The device took "${v.signature}" in ${v.index}:${v.sub}${v.name ? ` (${v.name})` : ''}; the values apply after a reset node.`);
});

/** fetch for the DCF endpoints (text, not JSON), with the page's token, errors as ApiError. */
async function dcfRequest(method, text) {
  const init = { method, headers: { accept: 'text/plain, application/json' } };
  if (text !== undefined) {
    init.headers['content-type'] = 'text/plain; charset=utf-8';
    init.body = text;
  }
  // Through apiFetch: with the page's token, as every request (issue 21).
  const response = await apiFetch(`${base}/config.dcf`, init);
  const answer = await response.text();
  if (!response.ok) {
    let data = null;
    try { data = JSON.parse(answer); } catch { /* not JSON: the status says it */ }
    throw new ApiError(describeError(response.status, data, `${method} config.dcf: HTTP ${response.status}`), {
      status: response.status, code: data?.error?.code || `http_${response.status}`, body: data,
    });
  }
  return { answer, response };
}

$('#dcf-download').addEventListener('click', async (event) => {
  result(configResult, 'busy', 'Reading every parameter for the backup…');
  const done = await runAction(event.currentTarget, 'Reading…', () => dcfRequest('GET'));
  if (!done.ok) {
    result(configResult, 'failed', h('strong', {}, `Backup failed (${clock()}): `), errorView(done.error));
    return;
  }
  const { answer, response } = done.value;
  const named = /filename="([^"]+)"/.exec(response.headers.get('content-disposition') || '');
  const file = named ? named[1] : `node${nodeId}.dcf`;
  const url = URL.createObjectURL(new Blob([answer], { type: 'text/plain' }));
  const link = h('a', { href: url, download: file, id: 'dcf-link' }, `Save ${file} again`);
  link.click();
  const entries = (answer.match(/^ParameterValue=/gm) || []).length;
  result(configResult, 'done', h('strong', {}, `Backup read (${clock()}): `),
    `${entries} parameter values, ${answer.length.toLocaleString()} bytes, downloaded as ${file}. `, link);
});

const dcfFile = $('#dcf-file');
const dcfRestore = $('#dcf-restore');
dcfFile.addEventListener('change', () => { dcfRestore.disabled = !dcfFile.files.length; });

dcfRestore.addEventListener('click', async () => {
  const file = dcfFile.files[0];
  if (!file) return;
  if (!(await confirmAction(`Write every value of ${file.name} to node ${nodeId}?`, 'Restore DCF'))) return;
  result(configResult, 'busy', `Writing ${file.name} to the device…`);
  const done = await runAction(dcfRestore, 'Writing…', async () => JSON.parse((await dcfRequest('PUT', await file.text())).answer));
  if (!done.ok) {
    const line = done.error.body?.error?.line;
    result(configResult, 'failed', h('strong', {}, `DCF restore failed (${clock()}): `), errorView(done.error),
      line ? ` (line ${line})` : '', h('div', { class: 'sub' }, 'Nothing was written when the file was refused before the bus.'));
    return;
  }
  const report = done.value;
  const failed = report.entries.filter((e) => !e.ok);
  const row = (e) => h('tr', { class: e.ok ? null : 'failed', dataset: { index: e.index, sub: e.sub } },
    h('td', { 'data-label': 'Object' }, h('code', {}, `${e.index}:${e.sub}`)),
    h('td', { 'data-label': 'Name' }, e.name),
    h('td', { 'data-label': 'Result' }, e.ok ? 'written' : errorView(e.error || { message: 'failed' })));
  const table = (list) => h('table', { class: 'grid dcf-report' },
    h('thead', {}, h('tr', {}, h('th', {}, 'Object'), h('th', {}, 'Name'), h('th', {}, 'Result'))),
    h('tbody', {}, list.map(row)));
  result(configResult, failed.length ? 'failed' : 'done',
    h('strong', {}, `DCF restore (${clock()}): ${report.written} written, ${report.failed} failed.`),
    failed.length ? table(failed) : null,
    h('details', {}, h('summary', {}, `Every entry (${report.entries.length})`), table(report.entries)));
  loadDetail();
});

// ---- object dictionary -----------------------------------------------------

const values = new Map(); // "0x1017:0" -> {value, raw, data_type, error, at}
let dictionary = []; // the objects of the last search
let searchController = null;

const INT = /^([iu])(\d+)$/;
const isInt = (type) => INT.test(type);
const bitsOf = (type) => Number(INT.exec(type)?.[2] || 0);
const readable = (access) => access !== 'wo';
const writable = (access) => ['rw', 'wo', 'rwr', 'rww'].includes(access);

/** An integer (number or decimal string) as two's-complement hex of its width. */
function toHex(value, type) {
  let big;
  try { big = BigInt(value); } catch { return String(value); }
  const bits = BigInt(bitsOf(type));
  if (big < 0n) big += 1n << bits;
  return `0x${big.toString(16).toUpperCase().padStart(Number(bits) / 4, '0')}`;
}

function showValue(value, type) {
  if (value === null || value === undefined) return '—';
  if (isInt(type) && hexToggle.checked) return toHex(value, type);
  if (typeof value === 'string') return value;
  return String(value);
}

function area(index) {
  const axes = detail && DRIVES.has(detail.profile) ? (detail.axes || []).length : 0;
  if (index < 0x1000) return { key: 0, title: 'Data types', range: [0x0001, 0x0fff] };
  if (index < 0x2000) return { key: 1, title: 'Communication', range: [0x1000, 0x1fff] };
  if (index < 0x6000) {
    // The UMC's per-axis manufacturer areas: axis n at 0x4000 + 0x200 (n-1).
    if (detail?.profile === 'umc' && index >= 0x4000) {
      const axis = Math.floor((index - 0x4000) / 0x200) + 1;
      if (axis <= axes) {
        const from = 0x4000 + 0x200 * (axis - 1);
        return { key: 20 + axis, title: `Manufacturer · axis ${axis}`, range: [from, from + 0x1ff] };
      }
    }
    if (detail?.profile === 'umc') return { key: 2, title: 'Manufacturer · board', range: [0x2000, 0x3fff] };
    return { key: 2, title: 'Manufacturer', range: [0x2000, 0x5fff] };
  }
  if (index < 0xa000) {
    // CiA 402 multi-axis devices: axis n's profile objects at 0x6000 + 0x800 (n-1).
    if (axes > 1 && index < 0x6000 + 0x800 * axes) {
      const axis = Math.floor((index - 0x6000) / 0x800) + 1;
      const from = 0x6000 + 0x800 * (axis - 1);
      return { key: 40 + axis, title: `Device profile · axis ${axis}`, range: [from, from + 0x7ff] };
    }
    return { key: 40, title: 'Device profile', range: [0x6000, 0x9fff] };
  }
  return { key: 90, title: 'Other', range: [0xa000, 0xffff] };
}

async function loadDictionary() {
  const q = search.value.trim();
  searchController?.abort();
  const controller = new AbortController();
  searchController = controller;
  odCount.textContent = q ? `Searching “${q}”…` : 'Loading…';
  try {
    dictionary = await api(`${base}/od${q ? `?q=${encodeURIComponent(q)}` : ''}`, { signal: controller.signal });
  } catch (error) {
    if (error.name === 'AbortError') return;
    odCount.textContent = '';
    odRoot.replaceChildren(h('p', { class: 'row-error' }, `Object dictionary: ${error.message}`));
    return;
  }
  if (controller !== searchController) return;
  renderDictionary(q);
}

function renderDictionary(q) {
  const subs = dictionary.reduce((n, o) => n + o.subs.length, 0);
  odCount.textContent = `${dictionary.length} objects, ${subs} entries${q ? ` matching “${q}”` : ''}`;
  if (dictionary.length === 0) {
    odRoot.replaceChildren(h('p', { class: 'placeholder' }, q ? `Nothing matches “${q}”.` : 'The node has no EDS: its dictionary is unknown.'));
    return;
  }
  const groups = new Map();
  for (const object of dictionary) {
    const a = area(parseInt(object.index, 16));
    if (!groups.has(a.key)) groups.set(a.key, { ...a, objects: [] });
    groups.get(a.key).objects.push(object);
  }
  const open = dictionary.length <= 3; // a narrow search opens what it found
  odRoot.replaceChildren(...[...groups.values()].sort((x, y) => x.key - y.key).map((g) => h('section', { class: 'od-area', dataset: { area: g.title } },
    h('h3', {}, g.title, ' ', h('span', { class: 'sub' }, `${hex(g.range[0], 4)}–${hex(g.range[1], 4)} · ${g.objects.length} objects`)),
    g.objects.map((object) => objectView(object, open)))));
  // What the search opened shows its values at once: one batch read.
  if (open) readObjects(dictionary);
}

const MAX_BATCH = 256; // POST .../od/read takes at most this many entries

/**
 * Reads every readable entry of `objects` in as few batch reads as the
 * API allows (one for what fits on a screen), and shows the values.
 * `status` (optional) says how it went.
 */
async function readObjects(objects, status = null) {
  const list = objects.flatMap((object) => object.subs.filter((s) => readable(s.access)).map((s) => [object.index, s.sub]));
  if (list.length === 0) return { read: 0, failed: 0 };
  if (status) {
    status.dataset.state = 'busy';
    status.textContent = `Reading ${list.length} entries…`;
  }
  let failed = 0;
  for (let from = 0; from < list.length; from += MAX_BATCH) {
    const batch = list.slice(from, from + MAX_BATCH);
    let answers;
    try {
      answers = await api(`${base}/od/read`, { method: 'POST', body: { entries: batch } });
    } catch (error) {
      if (status) {
        status.dataset.state = 'failed';
        status.replaceChildren(errorView(error));
      }
      throw error;
    }
    const at = clock();
    answers.forEach((answer, i) => {
      const key = `${batch[i][0]}:${batch[i][1]}`;
      if (answer.error) {
        failed += 1;
        values.set(key, { error: answer.error, at });
      } else {
        values.set(key, { value: answer.value, raw: answer.raw, data_type: answer.data_type, at });
      }
      refreshRow(key);
    });
  }
  if (status) {
    status.dataset.state = failed ? 'failed' : 'done';
    status.textContent = `Read ${list.length - failed} of ${list.length} (${clock()})`;
  }
  return { read: list.length - failed, failed };
}

function objectView(object, open) {
  const details = h('details', { class: 'od-object', dataset: { index: object.index } },
    h('summary', {},
      h('code', { class: 'od-index' }, object.index),
      h('span', { class: 'od-name' }, object.name),
      h('span', { class: 'sub' }, `${object.object_type}${object.subs.length > 1 ? ` · ${object.subs.length} subs` : ''}`)));
  let built = false;
  const build = (readNow) => {
    if (built || !details.open) return;
    built = true;
    details.append(objectBody(object));
    // Opened by hand: its values, read in one batch, not "not read".
    if (readNow) readObjects([object]).catch(() => {});
  };
  details.addEventListener('toggle', () => build(true));
  if (open) {
    details.open = true;
    build(false);
  }
  return details;
}

function objectBody(object) {
  const rows = object.subs.map((sub) => subRow(object, sub));
  const readList = object.subs.filter((s) => readable(s.access));
  const status = h('span', { class: 'od-status', role: 'status' });
  const readAll = h('button', { type: 'button', class: 'read-all' }, 'Read again');
  readAll.addEventListener('click', () => runAction(readAll, 'Reading…', () => readObjects([object], status)));
  return h('div', { class: 'od-body' },
    readList.length ? h('div', { class: 'od-actions' }, readAll, status) : null,
    h('table', { class: 'grid od-subs' },
      h('thead', {}, h('tr', {}, ['Sub', 'Name', 'Type', 'Access', 'Range', 'Value', ''].map((t) => h('th', {}, t)))),
      h('tbody', {}, rows)));
}

const rowsByKey = new Map(); // key -> {render}

function range(sub) {
  const parts = [];
  if (sub.low !== null && sub.low !== undefined) parts.push(`${sub.low} … ${sub.high ?? ''}`);
  else if (sub.high !== null && sub.high !== undefined) parts.push(`… ${sub.high}`);
  if (sub.default !== null && sub.default !== undefined) parts.push(`default ${sub.default}`);
  return parts.join(' · ') || '—';
}

function inputFor(sub) {
  const type = sub.data_type;
  const label = `New value of ${sub.name}`;
  if (type === 'bool') {
    return h('select', { 'aria-label': label }, h('option', { value: 'true' }, 'true'), h('option', { value: 'false' }, 'false'));
  }
  if (isInt(type) && bitsOf(type) > 32) {
    // 64-bit (and 40/48/56-bit) integers travel as decimal strings: a JS
    // number would round them.
    return h('input', { type: 'text', inputmode: 'numeric', pattern: type.startsWith('i') ? '-?[0-9]+' : '[0-9]+', 'aria-label': label, placeholder: 'integer' });
  }
  if (isInt(type)) {
    const bits = bitsOf(type);
    const min = sub.low ?? (type.startsWith('i') ? -(2 ** (bits - 1)) : 0);
    const max = sub.high ?? (type.startsWith('i') ? 2 ** (bits - 1) - 1 : 2 ** bits - 1);
    return h('input', { type: 'number', step: 1, min, max, 'aria-label': label, inputmode: 'numeric' });
  }
  if (type === 'r32' || type === 'r64') {
    return h('input', { type: 'number', step: 'any', min: sub.low, max: sub.high, 'aria-label': label });
  }
  if (type === 'vs' || type === 'us') return h('input', { type: 'text', 'aria-label': label, placeholder: 'text' });
  if (type === 'os') return h('input', { type: 'text', 'aria-label': label, placeholder: 'base64' });
  return null; // domains and types the page cannot edit
}

/** What an input of `type` takes, in words ("an integer from 0 to 255"). */
function expected(input, type) {
  const bounds = input.min !== '' && input.max !== '' ? ` from ${input.min} to ${input.max}` : '';
  if (isInt(type)) return `an integer${bounds} (${type})`;
  return `a number${bounds} (${type})`;
}

/** The input's content as the JSON value to send, or throws a message. */
function parseInput(input, type) {
  const text = input.value.trim();
  if (type === 'bool') return text === 'true';
  if (type === 'vs' || type === 'us' || type === 'os') return input.value;
  // A number field holds "" for what is no number ("abc"): say so, not "empty".
  if (input.type === 'number' && input.validity.badInput) throw new Error(`not a number: enter ${expected(input, type)}`);
  if (text === '') throw new Error(`enter a value first: ${expected(input, type)}`);
  if (isInt(type) && bitsOf(type) > 32) {
    if (!new RegExp(`^${input.pattern}$`).test(text)) throw new Error(`“${text}” is not ${expected(input, type)}`);
    return text;
  }
  const number = Number(text);
  if (!Number.isFinite(number)) throw new Error(`“${text}” is not ${expected(input, type)}`);
  if (isInt(type) && !Number.isInteger(number)) throw new Error(`${text} is not ${expected(input, type)}`);
  // A value out of the type's range goes to the gateway, which says why it refuses it.
  return number;
}

function subRow(object, sub) {
  const key = `${object.index}:${sub.sub}`;
  const valueCell = h('td', { 'data-label': 'Value', class: 'od-value' });
  const actions = h('div', { class: 'od-acts' });
  const input = writable(sub.access) ? inputFor(sub) : null;
  let readButton = null;
  let message = null; // a note about the last action, shown under the value

  const render = () => {
    const state = values.get(key);
    const parts = [];
    if (!state) parts.push(h('span', { class: 'sub' }, readable(sub.access) ? 'not read' : 'write only'));
    else if (state.error) parts.push(h('div', { class: 'od-error' }, errorView(state.error)));
    else {
      parts.push(h('output', { class: 'value' }, showValue(state.value, state.data_type || sub.data_type)));
      parts.push(h('div', { class: 'raw sub' }, `raw ${state.raw || '—'} · read ${state.at}`));
    }
    if (message) parts.push(message);
    valueCell.replaceChildren(...parts);
  };
  rowsByKey.set(key, { render });

  if (readable(sub.access)) {
    readButton = h('button', { type: 'button', class: 'read' }, 'Read');
    readButton.addEventListener('click', async () => {
      message = null;
      const done = await runAction(readButton, 'Reading…', () => api(`${base}/od/${object.index}/${sub.sub}`));
      const at = clock();
      if (done.ok) {
        values.set(key, { value: done.value.value, raw: done.value.raw, data_type: done.value.data_type, at });
        if (input && input.value === '' && input.tagName === 'INPUT') input.value = done.value.value;
        if (input && input.tagName === 'SELECT') input.value = String(done.value.value);
      } else values.set(key, { error: done.error.body?.error || { message: done.error.message }, at });
      render();
    });
  }
  const cells = [readButton];
  if (input) {
    const write = h('button', { type: 'submit', class: 'write' }, 'Write');
    const form = h('form', { class: 'od-write', novalidate: true }, input, write);
    form.addEventListener('submit', async (event) => {
      event.preventDefault();
      let value;
      try {
        value = parseInput(input, sub.data_type);
      } catch (error) {
        message = h('div', { class: 'od-error' }, error.message);
        render();
        return;
      }
      message = h('div', { class: 'sub' }, 'Writing…');
      render();
      const done = await runAction(write, 'Writing…', () => api(`${base}/od/${object.index}/${sub.sub}`, { method: 'PUT', body: { value } }));
      const at = clock();
      if (done.ok) {
        // What the device holds now: the gateway's read-back, not the input.
        values.set(key, { value: done.value.value, raw: done.value.raw, data_type: done.value.data_type, at });
        message = h('div', { class: 'od-done' }, `Written (${at}); the value above is read back from the device.`);
      } else {
        message = h('div', { class: 'od-error' }, `Write failed (${at}): `, errorView(done.error));
      }
      render();
    });
    cells.push(form);
  }
  actions.append(...cells.filter(Boolean));
  render();
  return h('tr', { dataset: { key, sub: sub.sub } },
    h('td', { 'data-label': 'Sub', class: 'num' }, String(sub.sub)),
    h('td', { 'data-label': 'Name' }, sub.name, sub.pdo_mappable ? h('span', { class: 'tag', title: 'PDO mappable' }, 'PDO') : null),
    h('td', { 'data-label': 'Type' }, h('code', {}, sub.data_type)),
    h('td', { 'data-label': 'Access' }, sub.access),
    h('td', { 'data-label': 'Range', class: 'sub' }, range(sub)),
    valueCell,
    h('td', { 'data-label': '', class: 'od-actions-cell' }, actions));
}

function refreshRow(key) {
  rowsByKey.get(key)?.render();
}

let searchTimer = null;
search.addEventListener('input', () => {
  clearTimeout(searchTimer);
  searchTimer = setTimeout(loadDictionary, 300);
});
hexToggle.addEventListener('change', () => {
  for (const row of rowsByKey.values()) row.render();
});

// ---- live ------------------------------------------------------------------

const mine = (data) => data && data.bus === bus && String(data.node) === nodeId;

stream.subscribe(['nodes'], (data, message) => {
  if (mine(data) && data.event === 'offline' && data.reason === 'node_id_changed') {
    showMoved();
    return;
  }
  if (message.lagged || mine(data)) loadDetail();
});
stream.subscribe(['emcy'], (data, message) => {
  if (message.lagged || mine(data)) loadDetail();
});

stream.onState(({ state, reconnected }) => {
  // Whatever happened while the page was away is read again.
  if (state === 'connected' && reconnected) loadDetail();
});

// An alarm's help links the objects it names here (`#od=0x603F`, alarms.js):
// the dictionary opens searched for that object.
const askedObject = /^#od=(0x[0-9a-f]{4})$/i.exec(window.location.hash);
if (askedObject) search.value = askedObject[1];

stream.connect();
loadDetail();


// Program download (CiA 302-3): the image goes to the gateway by
// XMLHttpRequest, whose upload reports progress (fetch's does not); the
// gateway then stops, clears, downloads, verifies and starts the program,
// and reports each step and the bytes the device has confirmed on the
// stream topic `.../program`, which moves the bar; the answer says how it
// ended.
const programFile = $('#program-file');
const programButton = $('#program-download');
const programProgress = $('#program-progress');
const programResult = $('#program-result');
let programSupported = null; // whether the node's EDS has 0x1F50 (null: not known yet)
programFile.addEventListener('change', () => { programButton.disabled = !programFile.files.length || programSupported === false; });

/** Whether the node can take a program at all: its EDS names the program
 * download object 0x1F50 (CiA 302-3). Asked of the dictionary (the EDS,
 * no device transfer), so a node without it is said before a file is
 * picked, not after the confirmation (issue 31 point 6). */
async function checkProgramSupport() {
  let found;
  try {
    found = await api(`${base}/od?q=0x1F50`);
  } catch {
    return; // the dictionary's own error shows in its panel
  }
  programSupported = found.some((o) => parseInt(o.index, 16) === 0x1f50);
  const panel = $('#program-panel');
  panel.dataset.supported = String(programSupported);
  programFile.disabled = !programSupported;
  $('#program-start').disabled = !programSupported;
  if (!programSupported) {
    programButton.disabled = true;
    result(programResult, 'failed', `This node's EDS${detail?.eds ? ` (${detail.eds})` : ''} has no program download object (0x1F50): it takes no program.`);
  } else if (programResult.dataset.state === 'failed' && !programResult.textContent.startsWith('Program')) {
    result(programResult, '', '');
  }
}

/** The software version (0x100A) the device now reports, or null. */
async function softwareVersion() {
  try {
    const [entry] = await api(`${base}/od/read`, { method: 'POST', body: { entries: [['0x100A', 0]] } });
    return entry && !entry.error ? String(entry.value) : null;
  } catch {
    return null;
  }
}
// The stream's runs: those up to `programRunSeen` were there before the
// last click and are left alone (the topic first gives how the last one
// ended); a later one moves the bar, and its text until the answer came.
let programRunSeen = 0;
let programRunShown = 0;
let programAnswered = true;
stream.subscribe([`buses/${bus}/nodes/${nodeId}/program`], (data) => {
  programRunShown = Math.max(programRunShown, data.run);
  if (data.run <= programRunSeen || programProgress.hidden) return;
  programProgress.value = data.percent;
  programProgress.dataset.stream = String(data.percent);
  if (data.state === 'running' && !programAnswered) {
    result(programResult, 'busy', `Step ${data.step_name}: `,
      `${data.bytes_sent.toLocaleString()} of ${data.bytes_total.toLocaleString()} bytes confirmed by the device (${data.percent} %)…`);
  }
});

async function postProgram(file, start) {
  await whenSignedIn();
  return new Promise((resolve, reject) => {
    const xhr = new XMLHttpRequest();
    xhr.open('POST', `/api/v1${base}/program${start ? '' : '?start=false'}`);
    xhr.setRequestHeader('content-type', 'application/octet-stream');
    xhr.setRequestHeader('accept', 'application/json');
    for (const [name, value] of Object.entries(authorization())) xhr.setRequestHeader(name, value);
    xhr.upload.addEventListener('progress', (event) => {
      if (event.lengthComputable) {
        result(programResult, 'busy', `Sending ${file.name} to the gateway: ${Math.round((100 * event.loaded) / event.total)} %…`);
      }
    });
    xhr.upload.addEventListener('load', () => {
      // Sent: the gateway now downloads it to the device; the stream
      // moves the bar.
      if (programProgress.dataset.stream === '') {
        result(programResult, 'busy', `${file.name} sent; the gateway downloads it to the device and verifies it…`);
      }
    });
    xhr.addEventListener('error', () => reject(new ApiError(`cannot reach the gateway (POST ${base}/program)`)));
    xhr.addEventListener('load', () => {
      let data = null;
      try { data = JSON.parse(xhr.responseText); } catch { /* not JSON: the status says it */ }
      if (xhr.status === 401) signInAgain();
      if (xhr.status !== 200) {
        reject(new ApiError(describeError(xhr.status, data, `POST program: HTTP ${xhr.status}`), {
          status: xhr.status, code: data?.error?.code || `http_${xhr.status}`, body: data,
        }));
        return;
      }
      resolve(data);
    });
    xhr.send(file);
  });
}

programButton.addEventListener('click', async () => {
  const file = programFile.files[0];
  if (!file) return;
  const start = $('#program-start').checked;
  if (!(await confirmAction(`Replace the program of node ${nodeId} with ${file.name} (${file.size.toLocaleString()} bytes)? The device's program stops first.`, 'Download program'))) return;
  programProgress.hidden = false;
  programProgress.value = 0;
  programProgress.dataset.stream = '';
  programRunSeen = programRunShown;
  programAnswered = false;
  result(programResult, 'busy', `Sending ${file.name}…`);
  const done = await runAction(programButton, 'Downloading…', () => postProgram(file, start));
  // The answer may come before the stream's last reports, which still
  // move the bar (a failed run's stays where the device stopped).
  programAnswered = true;
  if (done.ok) programProgress.value = 100;
  if (!done.ok) {
    const step = done.error.body?.error?.step;
    result(programResult, 'failed', h('strong', {}, `Program download failed (${clock()}): `),
      step ? `at step ${step}: ` : '', errorView(done.error));
    return;
  }
  const v = done.value;
  result(programResult, 'done', h('strong', {}, `Program downloaded (${clock()}): `),
    `${v.bytes.toLocaleString()} bytes in ${v.elapsed_ms} ms (${v.bytes_per_s.toLocaleString()} bytes/s), `,
    `0x1F56 = ${v.crc32_hex} verified; `, v.started ? 'the program was started.' : 'the program was left stopped.');
  // The version the device now reports (0x100A), where it has one.
  const version = await softwareVersion();
  if (version !== null) programResult.append(' ', h('span', { id: 'program-version' }, `Software version (0x100A): ${version}.`));
});
