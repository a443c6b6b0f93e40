// The I/O page of a CiA 401 module (/nodes/{bus}/{node}/io): every
// channel of GET .../io, read again twice a second (the inputs live, each
// with its age and where it came from); an output is set with PUT .../io,
// and what the page then shows is the value the gateway read back from the
// device, with whether it confirms what was asked.

import { api, runAction } from './api.js';
import { $, clock, h, showMessage } from './dom.js';
import { stream } from './layout.js';

const root = $('#io-page');
const bus = root.dataset.bus;
const node = root.dataset.node;
const base = `/buses/${encodeURIComponent(bus)}/nodes/${encodeURIComponent(node)}`;
const pageMessage = $('#page-message');
const result = $('#io-result');
const POLL_MS = 500;

const age = (c) => (c.source === 'tpdo' ? `TPDO, ${c.age_ms} ms ago` : 'read now (SDO)');

async function set(button, channel, value) {
  const done = await runAction(button, 'Setting…', () => api(`${base}/io`, { method: 'PUT', body: { outputs: { [channel]: value } } }));
  if (!done.ok) {
    result.dataset.state = 'failed';
    result.replaceChildren(h('strong', {}, `${channel} not set (${clock()}): `), done.error.message);
    return;
  }
  const out = done.value.outputs[0];
  result.dataset.state = out.confirmed ? 'done' : 'failed';
  result.replaceChildren(h('strong', { id: 'set-result', dataset: { channel: out.channel, confirmed: String(out.confirmed) } },
    `${out.channel} set to ${out.written}: the device reads back ${out.read_back}`),
  out.confirmed ? ' (confirmed)' : ' (NOT confirmed)', ` · ${clock()}`);
  refresh();
}

function lamp(c, output) {
  const on = c.value === true;
  return h('div', { class: 'lamp', id: `ch-${c.channel}`, dataset: { on: String(on), source: c.source } },
    h('span', { class: 'dot', 'aria-hidden': 'true' }),
    h('span', { class: 'label' }, c.channel),
    h('span', { class: 'state' }, on ? 'on' : 'off'),
    output
      ? h('button', { type: 'button', class: 'set', on: { click: (e) => set(e.currentTarget, c.channel, !on) } }, on ? 'Switch off' : 'Switch on')
      : h('span', { class: 'age' }, age(c)));
}

const drafts = new Map(); // analogue output -> the value being typed

function analog(c, output) {
  const children = [h('div', { class: 'label' }, c.channel), h('div', { class: 'value' }, String(c.value))];
  if (output) {
    const input = h('input', {
      type: 'number', min: '-32768', max: '32767', step: '1', 'aria-label': `New value of ${c.channel}`,
      value: drafts.get(c.channel) ?? String(c.value), on: { input: (e) => drafts.set(c.channel, e.target.value) },
    });
    children.push(h('div', {}, input, ' ', h('button', {
      type: 'button', class: 'set',
      on: { click: (e) => { const v = Number(input.value); drafts.delete(c.channel); set(e.currentTarget, c.channel, v); } },
    }, 'Set')));
  } else {
    children.push(h('div', { class: 'age' }, age(c)));
  }
  return h('div', { class: 'analog', id: `ch-${c.channel}` }, ...children);
}

let busy = false;
async function refresh() {
  if (busy) return;
  busy = true;
  try {
    const io = await api(`${base}/io`);
    showMessage(pageMessage, '');
    $('#digital-inputs').replaceChildren(...io.digital_inputs.map((c) => lamp(c, false)));
    $('#digital-outputs').replaceChildren(...io.digital_outputs.map((c) => lamp(c, true)));
    $('#analog-inputs').replaceChildren(...io.analog_inputs.map((c) => analog(c, false)));
    // An output being typed into is left alone until it is set.
    const focused = document.activeElement?.closest?.('#analog-outputs');
    if (!focused) $('#analog-outputs').replaceChildren(...io.analog_outputs.map((c) => analog(c, true)));
    root.dataset.loaded = 'true';
  } catch (error) {
    showMessage(pageMessage, `I/O: ${error.message}`);
  } finally {
    busy = false;
  }
}

refresh();
setInterval(refresh, POLL_MS);
// The connection indicator says whether the gateway is reachable, here too.
stream.connect();
