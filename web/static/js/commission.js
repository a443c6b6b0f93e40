// A commissioning page of a UMC (/nodes/{bus}/{node}/axes/{axis}/commissioning/{page}):
// the objects the profile lists for it (rendered into the table by the
// server, with their kind: Q15.16, a code, or an integer and its scale),
// read in one batch, shown in the manual's units; a writable one is typed
// in those units, written as its raw value and read back.

import { api, runAction } from './api.js';
import { $, clock, h, showMessage } from './dom.js';
import { stream } from './layout.js';

const root = $('#commission-page');
const base = `/buses/${encodeURIComponent(root.dataset.bus)}/nodes/${encodeURIComponent(root.dataset.node)}`;
const result = $('#result');
const rows = [...root.querySelectorAll('#objects tbody tr')];

/** A raw value in the row's units. */
export function human(kind, raw) {
  if (kind === 'q15') return +(raw / 65536).toFixed(4);
  if (kind === 'code') return `0x${(raw >>> 0).toString(16).toUpperCase().padStart(4, '0')}`;
  const scale = Number(kind);
  return +(raw * scale).toFixed(Math.max(0, Math.ceil(-Math.log10(scale)) + 1));
}

/** What was typed, as the raw value; NaN if it is no number. */
export function raw(kind, text) {
  const t = String(text).trim();
  if (kind === 'code') return /^0x[0-9a-f]+$/i.test(t) ? parseInt(t, 16) : (/^-?\d+$/.test(t) ? Number(t) : NaN);
  const v = Number(t);
  if (t === '' || !Number.isFinite(v)) return NaN;
  return Math.round(kind === 'q15' ? v * 65536 : v / Number(kind));
}

function show(row, entry) {
  const cell = row.querySelector('.value');
  const target = row.querySelector('.edit') || row.querySelector('.read');
  if (entry.error) {
    row.dataset.state = 'failed';
    cell.title = entry.error.message;
    if (target.tagName === 'INPUT') target.placeholder = 'unreadable'; else target.textContent = '—';
    return;
  }
  row.dataset.state = 'read';
  row.dataset.raw = String(entry.value);
  const text = String(human(row.dataset.kind, Number(entry.value)));
  if (target.tagName === 'INPUT') {
    if (document.activeElement !== target) target.value = text;
  } else {
    target.textContent = text;
  }
}

async function readAll() {
  try {
    const entries = rows.map((row) => [row.dataset.index, Number(row.dataset.sub)]);
    const answer = await api(`${base}/od/read`, { method: 'POST', body: { entries } });
    answer.forEach((entry, i) => show(rows[i], entry));
    showMessage($('#page-message'), '');
    // The values are one read, not live: say when (issue 31 point 6).
    const readAt = $('#read-at');
    readAt.textContent = `Read at ${clock()}`;
    readAt.dataset.at = String(Date.now());
  } catch (err) {
    showMessage($('#page-message'), err.message);
  }
  root.dataset.loaded = 'true';
}

for (const row of rows) {
  const button = row.querySelector('.write');
  if (!button) continue;
  button.addEventListener('click', async () => {
    const name = row.children[1].textContent;
    const value = raw(row.dataset.kind, row.querySelector('.edit').value);
    if (Number.isNaN(value)) {
      result.dataset.state = 'failed';
      result.textContent = `${name}: not a number.`;
      return;
    }
    const path = `${base}/od/${row.dataset.index}/${row.dataset.sub}`;
    const done = await runAction(button, 'Writing…', () => api(path, { method: 'PUT', body: { value } }));
    if (!done.ok) {
      result.dataset.state = 'failed';
      result.replaceChildren(h('strong', {}, `${name} not written (${clock()}): `), done.error.message);
      return;
    }
    show(row, done.value);
    row.dataset.written = 'true';
    result.dataset.state = 'done';
    result.replaceChildren(h('strong', { id: 'write-result', dataset: { index: row.dataset.index, sub: row.dataset.sub } },
      `${name} = ${human(row.dataset.kind, Number(done.value.value))} (${clock()}), read back.`));
  });
}

$('#refresh').addEventListener('click', readAll);

for (const [id, path, label] of [['#store', 'store', 'Storing…'], ['#restore', 'restore', 'Restoring…']]) {
  $(id).addEventListener('click', async (event) => {
    const done = await runAction(event.currentTarget, label, () => api(`${base}/${path}`, { method: 'POST', body: { what: 'all' } }));
    result.dataset.state = done.ok ? 'done' : 'failed';
    result.textContent = done.ok ? `${path === 'store' ? 'Stored' : 'Restored'} (${clock()}).` : `${path} failed: ${done.error.message}`;
    if (done.ok) readAll();
  });
}

readAll();
// The connection indicator says whether the gateway is reachable, here too.
stream.connect();
