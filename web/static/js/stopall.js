// STOP ALL in the top bar of every page (templates/base.html): one tap
// quick-stops every enabled axis on every bus (POST /stop-all), and the
// bar says what was stopped and what could not be. The page it is on
// hears of it through a `candeck:stopped` event on the document.

import { api, runAction } from './api.js';
import { clock, h } from './dom.js';

const button = document.getElementById('stop-all');
const result = document.getElementById('stop-result');

const axisName = (a) => `${a.bus} node ${a.node}${a.axis === null || a.axis === undefined ? '' : ` axis ${a.axis}`}`;

function show(state, ...content) {
  result.dataset.state = state;
  result.hidden = false;
  result.replaceChildren(...content);
}

const dismiss = h('button', { type: 'button', class: 'stop-dismiss', 'aria-label': 'Hide the STOP ALL result', title: 'Hide' });
dismiss.addEventListener('click', () => {
  result.hidden = true;
  result.replaceChildren();
});

button.addEventListener('click', async () => {
  show('busy', 'Stopping every enabled axis…');
  const outcome = await runAction(button, 'STOPPING…', () => api('/stop-all', { method: 'POST' }));
  const at = clock();
  if (!outcome.ok) {
    show('failed', h('strong', {}, `STOP ALL failed (${at}): `), outcome.error.message, dismiss);
    return;
  }
  const { stopped, failed } = outcome.value;
  const parts = [];
  if (stopped.length) {
    parts.push(h('p', { class: 'stopped' }, h('strong', {}, `Stopped ${stopped.length} ${stopped.length > 1 ? 'axes' : 'axis'} (${at}): `),
      stopped.map(axisName).join(', ')));
  } else if (failed.length) {
    parts.push(h('p', { class: 'stopped' }, h('strong', {}, `No axis stopped (${at}).`)));
  } else {
    parts.push(h('p', { class: 'stopped' }, h('strong', {}, `Nothing to stop (${at}): `), 'no axis was in operation enabled.'));
  }
  if (failed.length) {
    parts.push(h('p', { class: 'failed' }, h('strong', {}, `Could not stop ${failed.length}:`)),
      h('ul', { class: 'failed' }, failed.map((f) => h('li', {}, `${axisName(f)}: ${f.error?.message || 'failed'}`))));
  }
  show(failed.length ? 'failed' : 'done', ...parts, dismiss);
  document.dispatchEvent(new CustomEvent('candeck:stopped', { detail: outcome.value }));
});

// The top bar's height, for what sticks under it (the drive page's stop bar).
const bar = document.querySelector('.topbar');
const measure = () => document.documentElement.style.setProperty('--topbar-height', `${bar.offsetHeight}px`);
new ResizeObserver(measure).observe(bar);
measure();
