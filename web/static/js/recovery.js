// Machine-level recovery (docs/alarms.md, "Machine-level recovery"): "Reset
// all faults" and "Enable all" for a bus, on the overview's machine card
// and the alarm page. Each asks once; the reset's question also offers to
// enable the axes right after it, so two faulted axes are back in
// operation enabled in two taps once their causes are gone. The result,
// per axis with the gateway's reason for each refusal, shows beside the
// buttons, where the tap was.

import { api, runAction } from './api.js';
import { clock, h } from './dom.js';

const OUTCOME = { done: 'done', not_needed: 'nothing to do', refused: 'refused' };

/** Asks in a modal dialog with `choices` ([{label, value, kind}]); resolves
 * the value chosen, or null for Cancel (and Esc). */
function ask(text, choices) {
  return new Promise((resolve) => {
    const dialog = h('dialog', { class: 'recovery-confirm', 'aria-label': 'Confirm' });
    const finish = (value) => {
      dialog.close();
      dialog.remove();
      resolve(value);
    };
    dialog.addEventListener('cancel', (event) => {
      event.preventDefault();
      finish(null);
    });
    dialog.append(h('p', {}, text), h('div', { class: 'buttons' },
      h('button', { type: 'button', class: 'cancel', on: { click: () => finish(null) } }, 'Cancel'),
      choices.map((c) => h('button', { type: 'button', class: c.kind || 'primary', dataset: { choice: c.value }, on: { click: () => finish(c.value) } }, c.label))));
    document.body.append(dialog);
    dialog.showModal();
  });
}

function axisLine(a) {
  return h('li', { class: `outcome ${a.outcome}`, dataset: { node: a.node, axis: a.axis, outcome: a.outcome } },
    h('strong', {}, `node ${a.node} axis ${a.axis}: `), OUTCOME[a.outcome] || a.outcome,
    a.state ? ` (${a.state.replaceAll('_', ' ')})` : '',
    a.reason ? h('span', { class: 'reason' }, `: ${a.reason}`) : '');
}

function report(title, answer) {
  const refused = answer.axes.filter((a) => a.outcome === 'refused');
  const p = h('p', {}, h('strong', {}, `${title} (${clock()}): `),
    answer.axes.length ? `${answer.axes.length - refused.length} of ${answer.axes.length} axes ${refused.length ? 'done, ' : 'done'}` : 'no axis to act on',
    refused.length ? `${refused.length} refused` : '');
  return [p, answer.axes.length ? h('ul', {}, answer.axes.map(axisLine)) : null];
}

/** The two buttons for `bus` and the element that shows their result;
 * `onDone()` runs after each action (to read the machine again). */
export function recoveryControls(bus, onDone = () => {}) {
  const base = `/buses/${encodeURIComponent(bus)}/machine`;
  const result = h('div', { class: 'recovery-result', role: 'status', 'aria-live': 'polite', dataset: { bus } });
  result.hidden = true;
  const show = (state, ...content) => {
    result.dataset.state = state;
    result.hidden = false;
    result.replaceChildren(...content.flat());
  };
  const reset = h('button', { type: 'button', class: 'recovery reset-faults', dataset: { bus } }, 'Reset all faults');
  const enable = h('button', { type: 'button', class: 'recovery enable-all', dataset: { bus } }, 'Enable all');

  async function run(button, busy, path, title) {
    const outcome = await runAction(button, busy, () => api(`${base}/${path}`, { method: 'POST', body: {} }));
    if (!outcome.ok) {
      show('failed', h('strong', {}, `${title} failed (${clock()}): `), outcome.error.message);
      return false;
    }
    const refused = outcome.value.axes.some((a) => a.outcome === 'refused');
    show(refused ? 'failed' : 'done', report(title, outcome.value));
    return !refused;
  }

  reset.addEventListener('click', async () => {
    const choice = await ask(`Reset the faults of every faulted axis on ${bus}? An axis whose cause is still present is refused.`, [
      { label: 'Reset faults', value: 'reset' },
      { label: 'Reset, then enable all', value: 'reset-enable' },
    ]);
    if (!choice) return;
    const reported = [];
    const ok = await run(reset, 'Resetting…', 'reset-faults', `Reset faults on ${bus}`);
    reported.push(...result.childNodes);
    if (ok && choice === 'reset-enable') {
      await run(enable, 'Enabling…', 'enable', `Enable all on ${bus}`);
      result.prepend(...reported);
    }
    onDone();
  });
  enable.addEventListener('click', async () => {
    const choice = await ask(`Enable every axis of ${bus} that was last in operation enabled? Those axes will hold their position under power.`, [
      { label: 'Enable all', value: 'enable' },
    ]);
    if (!choice) return;
    await run(enable, 'Enabling…', 'enable', `Enable all on ${bus}`);
    onDone();
  });
  return { buttons: h('div', { class: 'recovery-buttons', dataset: { bus } }, reset, enable), result };
}
