// The alarm bar under the top bar of every page (templates/base.html,
// docs/alarms.md): the active alarms counted by severity and the newest
// one's text, red while any is active and unacknowledged, from the
// stream's `alarms` topic (so it changes as the gateway raises or clears
// one, without a poll). Tapping it opens the alarm page. The page title
// carries the count of active unacknowledged alarms, so a tab in the
// background shows it. Pages that show alarms themselves (the overview's
// summary, the alarm page) listen with onAlarms().

import { h } from './dom.js';
import { stream } from './layout.js';

export const SEVERITIES = ['critical', 'high', 'medium', 'low'];
const RANK = Object.fromEntries(SEVERITIES.map((s, i) => [s, i]));

const bar = document.getElementById('alarm-bar');
const baseTitle = document.title;
const open = new Map(); // id -> every alarm that is not `normal`
const listeners = new Set();
let heard = false; // the topic's first `open` has come

export const isActive = (a) => a.state === 'active_unacknowledged' || a.state === 'active_acknowledged';
export const isUnacknowledged = (a) => a.state === 'active_unacknowledged' || a.state === 'cleared_unacknowledged';

/** The open alarms in a summary: counts of the active ones by severity,
 * how many are active and unacknowledged, cleared and unacknowledged, and
 * the newest (the most severe of the newest active, else any). */
export function summarize(alarms) {
  const active = Object.fromEntries(SEVERITIES.map((s) => [s, 0]));
  let activeUnacknowledged = 0;
  let clearedUnacknowledged = 0;
  for (const a of alarms) {
    if (isActive(a)) active[a.severity] = (active[a.severity] || 0) + 1;
    if (a.state === 'active_unacknowledged') activeUnacknowledged += 1;
    if (a.state === 'cleared_unacknowledged') clearedUnacknowledged += 1;
  }
  const newest = [...alarms].sort((a, b) => (isActive(b) - isActive(a))
    || (Date.parse(b.raised) - Date.parse(a.raised)) || (RANK[a.severity] - RANK[b.severity]) || (b.id - a.id))[0] || null;
  const activeCount = SEVERITIES.reduce((n, s) => n + active[s], 0);
  return { active, activeCount, activeUnacknowledged, clearedUnacknowledged, newest };
}

/** Where an alarm comes from, in words: "demo · node 1 · axis 2". */
export function source(a) {
  return [a.bus, a.node ? `node ${a.node}` : null, a.axis ? `axis ${a.axis}` : null].filter(Boolean).join(' · ');
}

/** Calls `fn(alarms, summary)` at each change of the open alarms (and now,
 * once they are known); returns a function that stops it. */
export function onAlarms(fn) {
  listeners.add(fn);
  if (heard) fn([...open.values()], summarize(open.values()));
  return () => listeners.delete(fn);
}

function render() {
  const alarms = [...open.values()];
  const s = summarize(alarms);
  const state = s.activeUnacknowledged ? 'unacknowledged' : s.activeCount ? 'active' : s.clearedUnacknowledged ? 'cleared' : 'quiet';
  bar.dataset.state = state;
  bar.dataset.activeUnacknowledged = String(s.activeUnacknowledged);
  const counts = SEVERITIES.filter((sev) => s.active[sev]).map((sev) => h('span', { class: `alarm-count ${sev}`, dataset: { severity: sev } }, `${s.active[sev]} ${sev}`));
  if (s.clearedUnacknowledged) counts.push(h('span', { class: 'alarm-count cleared' }, `${s.clearedUnacknowledged} cleared, not acknowledged`));
  const words = state === 'quiet' ? 'No active alarms' : s.newest ? `${source(s.newest)}: ${s.newest.text}` : '';
  bar.replaceChildren(
    h('span', { class: 'alarm-icon', 'aria-hidden': 'true' }),
    h('span', { class: 'alarm-counts' }, counts.length ? counts : null),
    h('span', { class: 'alarm-newest', id: 'alarm-newest' }, words),
    h('span', { class: 'alarm-open' }, 'Alarms ›'),
  );
  bar.title = state === 'quiet' ? 'No active alarms: open the alarm history' : 'Open the alarms';
  document.title = s.activeUnacknowledged ? `(${s.activeUnacknowledged}) ${baseTitle}` : baseTitle;
  for (const fn of listeners) fn(alarms, s);
}

stream.subscribe(['alarms'], (data, message) => {
  if (message.lagged || !data) return; // the open alarms come again after a `lagged`
  if (data.event === 'open') {
    open.clear();
    for (const a of data.alarms) open.set(a.id, a);
  } else if (data.alarm) {
    if (data.alarm.state === 'normal') open.delete(data.alarm.id);
    else open.set(data.alarm.id, data.alarm);
  }
  heard = true;
  bar.dataset.heard = 'yes';
  render();
});

render();
