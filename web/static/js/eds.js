// The device descriptions page (/eds): the EDS catalog as GET /eds lists
// it, each file's problems (file:line, key, what the reader did) and the
// nodes it describes; admins upload (POST /eds?name=) and delete uploaded
// files (DELETE /eds/{name}). The list shown is always the gateway's
// answer, read again after every change.

import { api, ApiError, describeError, runAction } from './api.js';
import { authorization, whenSignedIn } from './auth.js';
import { $, clock, h, showMessage } from './dom.js';
import { stream } from './layout.js';

const pageMessage = $('#page-message');
const tbody = $('#eds tbody');
const count = $('#eds-count');
const uploadPanel = $('#upload-panel');
const uploadFile = $('#upload-file');
const uploadName = $('#upload-name');
const uploadButton = $('#upload');
const uploadResult = $('#upload-result');

const hex = (n, width = 8) => (n === null || n === undefined ? '—' : `0x${n.toString(16).toUpperCase().padStart(width, '0')}`);
const SOURCES = { built_in: 'built in', dir: '--eds-dir', uploaded: 'uploaded' };
let admin = false;
const open = new Set(); // names whose problems are shown

function problemItem(file, problem) {
  const where = problem.line ? `${file}:${problem.line}` : file;
  return h('li', {},
    h('span', { class: 'where' }, where), ' ',
    problem.key ? h('code', {}, problem.key) : null, ' ',
    problem.action ? h('span', { class: 'action' }, problem.action) : null, ' ',
    problem.message);
}

function nodeLinks(nodes) {
  if (!nodes.length) return h('span', { class: 'sub' }, 'none');
  return nodes.flatMap((n, i) => [i ? ', ' : '',
    h('a', { href: `/nodes/${encodeURIComponent(n.bus)}/${n.node}` }, `${n.bus} ${n.node}`),
    n.assigned ? h('span', { class: 'sub' }, ' (assigned)') : null]);
}

function rows(file) {
  const warnings = file.warnings.length;
  const errors = file.errors.length;
  // The product's and vendor's names first (what a reader knows a device
  // by), then the numbers a device's 0x1018 is matched against.
  const named = file.product_name || file.vendor_name
    ? [h('span', { class: 'product' },
      h('strong', {}, file.product_name || 'unnamed product'),
      file.vendor_name ? h('span', { class: 'sub vendor' }, ` ${file.vendor_name}`) : null), h('br')]
    : [];
  const identity = file.vendor_id === null && file.product_code === null
    ? [...named, h('span', { class: 'sub' }, 'none: assign by hand')]
    : [...named, `vendor ${hex(file.vendor_id)}`, h('br'), `product ${hex(file.product_code)}`,
      file.revision !== null ? [h('br'), `revision ${hex(file.revision)}`] : null,
      file.matches_by_identity ? null : [h('br'), h('span', { class: 'sub' }, 'matched by hand only')]].flat();
  const toggle = h('button', {
    type: 'button', class: 'toggle-problems', 'aria-expanded': String(open.has(file.name)),
    disabled: warnings + errors === 0,
    on: { click: () => { if (open.has(file.name)) open.delete(file.name); else open.add(file.name); load(); } },
  }, open.has(file.name) ? 'Hide problems' : 'Problems');
  const remove = admin && file.source === 'uploaded'
    ? h('button', { type: 'button', class: 'danger delete', on: { click: (e) => removeFile(e.currentTarget, file.name) } }, 'Delete')
    : null;
  const row = h('tr', { dataset: { name: file.name, source: file.source } },
    h('td', { class: 'name', 'data-label': 'File' }, file.name),
    h('td', { 'data-label': 'Source' }, SOURCES[file.source] || file.source),
    h('td', { 'data-label': 'Identity' }, identity),
    h('td', { 'data-label': 'Device type' }, file.device_type === null ? '—'
      : [hex(file.device_type), file.profile ? h('span', { class: 'sub' }, ` ${file.profile}`) : null]),
    h('td', { 'data-label': 'Objects' }, file.objects ?? '—'),
    h('td', { class: warnings ? 'warnings count-warn' : 'warnings', 'data-label': 'Warnings' }, String(warnings)),
    h('td', { class: errors ? 'errors count-bad' : 'errors', 'data-label': 'Errors' }, String(errors)),
    h('td', { class: 'nodes', 'data-label': 'Nodes' }, nodeLinks(file.nodes)),
    h('td', {}, toggle, ' ', remove));
  if (!open.has(file.name)) return [row];
  const details = h('tr', { class: 'problems', dataset: { name: file.name } },
    h('td', { colspan: '9' },
      ...(errors ? [h('strong', {}, 'Errors'), h('ul', { class: 'problem-list errors-list' }, file.errors.map((p) => problemItem(file.name, p)))] : []),
      ...(warnings ? [h('strong', {}, 'Warnings'), h('ul', { class: 'problem-list warnings-list' }, file.warnings.map((p) => problemItem(file.name, p)))] : [])));
  return [row, details];
}

async function load() {
  let list;
  try {
    list = await api('/eds');
  } catch (error) {
    showMessage(pageMessage, `The catalog: ${error.message}`);
    return;
  }
  showMessage(pageMessage, '');
  const usable = list.files.filter((f) => f.usable).length;
  count.textContent = `${list.files.length} files, ${usable} usable`;
  tbody.replaceChildren(...list.files.flatMap(rows));
  $('#upload-where').textContent = list.uploads_kept_in === 'data_dir'
    ? 'Uploaded files are kept in the data directory (eds/).'
    : 'The gateway has no data directory: uploaded files are kept in memory until it stops.';
  document.getElementById('eds-page').dataset.loaded = 'true';
}

async function removeFile(button, name) {
  const done = await runAction(button, 'Deleting…', () => api(`/eds/${encodeURIComponent(name)}`, { method: 'DELETE' }));
  if (!done.ok) showMessage(pageMessage, `Delete ${name}: ${done.error.message}`);
  else showMessage(pageMessage, `${name} deleted (${clock()}).`, 'info');
  load();
}

/** POST /eds?name= with the file's bytes as they are (not JSON). */
async function upload(name, file) {
  const response = await fetch(`/api/v1/eds?name=${encodeURIComponent(name)}`, {
    method: 'POST',
    headers: { accept: 'application/json', 'content-type': 'text/plain', ...authorization() },
    body: await file.arrayBuffer(),
  });
  const text = await response.text();
  let data = null;
  try { data = JSON.parse(text); } catch { /* the status says it */ }
  if (!response.ok) {
    throw new ApiError(describeError(response.status, data, `upload: HTTP ${response.status}`), {
      status: response.status, code: data?.error?.code || `http_${response.status}`, body: data,
    });
  }
  return data;
}

uploadFile.addEventListener('change', () => {
  const file = uploadFile.files[0];
  if (file && !uploadName.value) uploadName.value = file.name;
  uploadButton.disabled = !file;
});

uploadButton.addEventListener('click', async () => {
  const file = uploadFile.files[0];
  if (!file) return;
  const name = uploadName.value.trim() || file.name;
  const done = await runAction(uploadButton, 'Uploading…', () => upload(name, file));
  if (!done.ok) {
    const line = done.error.body?.error?.line;
    uploadResult.dataset.state = 'failed';
    uploadResult.replaceChildren(h('strong', {}, `Refused (${clock()}): `), done.error.message, line ? ` (line ${line})` : '');
  } else {
    const kept = done.value;
    uploadResult.dataset.state = 'done';
    uploadResult.replaceChildren(h('strong', {}, `${kept.name} kept (${clock()}): `),
      `${kept.objects} objects, ${kept.warnings.length} warnings.`);
    if (kept.warnings.length) open.add(kept.name);
  }
  load();
});

async function start() {
  const me = await whenSignedIn();
  admin = !me || me.role === 'admin';
  uploadPanel.hidden = !admin;
  load();
}

start();
// The connection indicator says whether the gateway is reachable, here too.
stream.connect();
