// The alarm page (/alarms, docs/alarms.md): active alarms first, then the
// cleared ones waiting for an acknowledgement, then the history, as
// GET /alarms orders them, 50 a page; filters by node, severity and time;
// acknowledge one or all shown (who and when are the gateway's to record);
// each alarm's help with its objects linked to the node's page; and the
// machine-level recovery of each bus. The list is read again at each
// change of the stream's `alarms` topic.

import { api, runAction } from './api.js';
import { $, clock, h, showMessage, updateRows } from './dom.js';
import { stream } from './layout.js';
import { onAlarms, source } from './alarmbar.js';
import { recoveryControls } from './recovery.js';

const PAGE_SIZE = 50;
const STATE = {
  active_unacknowledged: 'active, not acknowledged',
  active_acknowledged: 'active, acknowledged',
  cleared_unacknowledged: 'cleared, not acknowledged',
  normal: 'history',
};
const GROUP = {
  active_unacknowledged: 'Active', active_acknowledged: 'Active',
  cleared_unacknowledged: 'Cleared, not acknowledged', normal: 'History',
};

const list = $('#alarm-list');
const pageMessage = $('#page-message');
const nodeFilter = $('#filter-node');
const severityFilter = $('#filter-severity');
const sinceFilter = $('#filter-since');
const ackShown = $('#ack-shown');
const ackResult = $('#ack-result');
const prev = $('#page-prev');
const next = $('#page-next');
const pageInfo = $('#page-info');
const recovery = $('#recovery-buses');

let page = 1;
let shown = []; // the alarms of the page shown
let reading = null; // the AbortController of the list's read in flight

const when = (time) => (time ? `${new Date(time).toLocaleDateString()} ${clock(Date.parse(time))}` : '');
const waits = (a) => a.state === 'active_unacknowledged' || a.state === 'cleared_unacknowledged';

/** The help's text with each object it names (0x603F, 0x1018 sub 2) a link
 * to the node's page, searching its dictionary for it. */
function helpText(a) {
  if (!a.node) return [a.help];
  const parts = [];
  let at = 0;
  for (const match of a.help.matchAll(/0x[0-9A-Fa-f]{4}\b/g)) {
    parts.push(a.help.slice(at, match.index));
    parts.push(h('a', {
      href: `/nodes/${encodeURIComponent(a.bus)}/${a.node}#od=${match[0]}`, class: 'object-link',
      title: `Object ${match[0]} of node ${a.node}`,
    }, match[0]));
    at = match.index + match[0].length;
  }
  parts.push(a.help.slice(at));
  return parts;
}

function filters() {
  const query = new URLSearchParams();
  const node = Number(nodeFilter.value);
  if (nodeFilter.value && Number.isInteger(node) && node >= 1 && node <= 127) query.set('node', String(node));
  if (severityFilter.value) query.set('severity', severityFilter.value);
  if (sinceFilter.value) query.set('since', String(Date.now() - Number(sinceFilter.value)));
  return query;
}

async function acknowledge(button, a) {
  const outcome = await runAction(button, 'Acknowledging…', () => api(`/alarms/${a.id}/ack`, { method: 'POST', body: {} }));
  if (!outcome.ok) showMessage(pageMessage, `Alarm ${a.id}: ${outcome.error.message}`);
  else showMessage(pageMessage, '');
  load();
}

function row(a) {
  const ack = waits(a)
    ? h('button', { type: 'button', class: 'house-button primary ack', dataset: { id: a.id } }, 'Acknowledge')
    : null;
  ack?.addEventListener('click', () => acknowledge(ack, a));
  return h('li', { class: `alarm ${a.severity}`, dataset: { key: `alarm ${a.id}`, id: a.id, state: a.state, severity: a.severity, kind: a.kind } },
    h('div', { class: 'alarm-head' },
      h('span', { class: `severity ${a.severity}` }, a.severity),
      h('span', { class: 'alarm-state' }, STATE[a.state] || a.state),
      h('span', { class: 'alarm-source' }, source(a)),
      a.count > 1 ? h('span', { class: 'alarm-repeats', title: 'Times its cause came back before it was acknowledged' }, `×${a.count}`) : null),
    h('p', { class: 'alarm-text' }, a.text),
    h('p', { class: 'alarm-times sub' },
      `Raised ${when(a.raised)}`, a.cleared ? ` · cleared ${when(a.cleared)}` : ' · cause present',
      ` · #${a.id}`),
    a.acknowledged_by
      ? h('p', { class: 'alarm-ack' }, `Acknowledged by `, h('strong', { class: 'who' }, a.acknowledged_by),
        ` at ${when(a.acknowledged_at)}`, a.comment ? ` — “${a.comment}”` : '')
      : null,
    a.help ? h('details', { class: 'alarm-help' }, h('summary', {}, 'What to look at'), h('p', {}, helpText(a))) : null,
    ack);
}

function render(alarms, total) {
  shown = alarms;
  const items = [];
  let group = null;
  for (const a of alarms) {
    if (GROUP[a.state] !== group) {
      group = GROUP[a.state];
      items.push(h('li', { class: 'group', dataset: { key: `group ${group}` } }, h('h2', {}, group)));
    }
    items.push(row(a));
  }
  if (!alarms.length) items.push(h('li', { class: 'placeholder', dataset: { key: 'none' } }, filters().toString() ? 'No alarm matches these filters.' : 'No alarm yet.'));
  // Kept where unchanged: a redraw at an alarm's change must not take
  // an Acknowledge away between touch and release.
  updateRows(list, items);
  const pages = Math.max(1, Math.ceil(total / PAGE_SIZE));
  pageInfo.textContent = `Page ${page} of ${pages} · ${total} alarm${total === 1 ? '' : 's'}`;
  prev.disabled = page <= 1;
  next.disabled = page >= pages;
  ackShown.disabled = !alarms.some(waits);
}

async function load() {
  reading?.abort();
  const controller = new AbortController();
  reading = controller;
  const query = filters();
  query.set('page', String(page));
  try {
    const answer = await api(`/alarms?${query}`, { signal: controller.signal });
    if (reading !== controller) return;
    const pages = Math.max(1, Math.ceil(answer.total / PAGE_SIZE));
    if (page > pages) {
      page = pages;
      load();
      return;
    }
    render(answer.alarms, answer.total);
  } catch (error) {
    if (error.name === 'AbortError') return;
    showMessage(pageMessage, `Alarms: ${error.message}`);
  }
}

ackShown.addEventListener('click', async () => {
  const waiting = shown.filter(waits);
  const outcome = await runAction(ackShown, 'Acknowledging…', async () => {
    const failed = [];
    for (const a of waiting) {
      try {
        await api(`/alarms/${a.id}/ack`, { method: 'POST', body: {} });
      } catch (error) {
        failed.push(`#${a.id}: ${error.message}`);
      }
    }
    return failed;
  });
  const failed = outcome.ok ? outcome.value : [outcome.error.message];
  ackResult.dataset.state = failed.length ? 'failed' : 'done';
  ackResult.textContent = failed.length
    ? `Acknowledged ${waiting.length - failed.length} of ${waiting.length} (${clock()}); ${failed.join(' · ')}`
    : `Acknowledged ${waiting.length} alarm${waiting.length === 1 ? '' : 's'} (${clock()}).`;
  load();
});

for (const input of [nodeFilter, severityFilter, sinceFilter]) {
  input.addEventListener('change', () => {
    page = 1;
    load();
  });
}
prev.addEventListener('click', () => {
  page = Math.max(1, page - 1);
  load();
});
next.addEventListener('click', () => {
  page += 1;
  load();
});

// A change of any alarm reads the page again (a few changes at once, once).
let again = null;
onAlarms(() => {
  clearTimeout(again);
  again = setTimeout(load, 100);
});

async function loadRecovery() {
  try {
    const buses = await api('/buses');
    recovery.replaceChildren(...buses.map((bus) => {
      const { buttons, result } = recoveryControls(bus.name, load);
      return h('div', { class: 'recovery-bus', dataset: { bus: bus.name } }, h('h3', {}, bus.name), buttons, result);
    }));
  } catch (error) {
    showMessage(pageMessage, `Buses: ${error.message}`);
  }
}

stream.onState(({ state, reconnected }) => {
  if (state === 'connected' && reconnected) load();
});

stream.connect();
load();
loadRecovery();
