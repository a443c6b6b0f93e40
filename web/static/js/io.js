// The I/O page of a CiA 401 module (/nodes/{bus}/{node}/io): every
// channel of GET .../io, read again twice a second (the inputs live, each
// with its age and where it came from); an output is set with PUT .../io,
// and what the page then shows is the value the gateway read back from the
// device, with whether it confirms what was asked.
//
// Each channel's element is made once and updated in place by every read:
// a button replaced under a finger between touch and release loses the tap,
// and a field replaced while typed into loses what was typed.

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
// An input older than this is greyed out: the module's TPDOs come at least
// every second while it is operational.
const STALE_MS = 2000;
const NMT = { operational: 'operational', pre_operational: 'pre-operational', stopped: 'stopped', boot_up: 'boot-up', unknown: 'unknown' };
const nodeState = $('#io-node-state');

const age = (c) => (c.source === 'tpdo' ? `TPDO, ${c.age_ms} ms ago` : 'read now (SDO)');
const staleAge = (c) => (c.source === 'tpdo' && c.age_ms > STALE_MS);

// Issue 31 point 6: a stopped or offline node answers no read, and its
// inputs are what they were when it stopped: each channel is greyed out
// with when it was last read, until the node runs again.
let lastRead = null; // Date.now() of the last read of the channels
function markAll(stale, why) {
  for (const container of root.querySelectorAll('.lamps, .analogs')) {
    for (const view of container.views?.views.values() || []) view.stale(stale, why);
  }
}

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

/** A digital channel: its lamp, and a switch for an output. */
function lamp(channel, output) {
  let on = false;
  const state = h('span', { class: 'state' });
  const tail = output
    ? h('button', { type: 'button', class: 'set', on: { click: (e) => set(e.currentTarget, channel, !on) } })
    : h('span', { class: 'age' });
  const el = h('div', { class: 'lamp', id: `ch-${channel}` },
    h('span', { class: 'dot', 'aria-hidden': 'true' }), h('span', { class: 'label' }, channel), state, tail);
  const update = (c) => {
    on = c.value === true;
    el.dataset.on = String(on);
    el.dataset.source = c.source;
    state.textContent = on ? 'on' : 'off';
    // A switch being set keeps its busy label; the read after the set
    // gives it the new one.
    if (!output) tail.textContent = age(c);
    else if (!tail.disabled) tail.textContent = on ? 'Switch off' : 'Switch on';
    stale(!output && staleAge(c), '');
  };
  const stale = (yes, why) => {
    el.dataset.stale = yes ? 'yes' : 'no';
    el.classList.toggle('stale', yes);
    if (output) tail.disabled = yes && Boolean(why);
    else if (why) tail.textContent = why;
  };
  return { el, update, stale };
}

const drafts = new Map(); // analogue output -> the value being typed

/** An analogue channel: its value, and a field and a button for an output. */
function analog(channel, output) {
  const value = h('div', { class: 'value' });
  const el = h('div', { class: 'analog', id: `ch-${channel}` }, h('div', { class: 'label' }, channel), value);
  let input = null;
  let ageEl = null;
  if (output) {
    input = h('input', {
      type: 'number', min: '-32768', max: '32767', step: '1', 'aria-label': `New value of ${channel}`,
      on: { input: (e) => drafts.set(channel, e.target.value) },
    });
    el.append(h('div', {}, input, ' ', h('button', {
      type: 'button', class: 'set',
      on: { click: (e) => { const v = Number(input.value); drafts.delete(channel); set(e.currentTarget, channel, v); } },
    }, 'Set')));
  } else {
    ageEl = h('div', { class: 'age' });
    el.append(ageEl);
  }
  const update = (c) => {
    value.textContent = String(c.value);
    if (ageEl) ageEl.textContent = age(c);
    // A field being typed into, or holding a value typed but not yet set,
    // keeps it.
    if (input && document.activeElement !== input && !drafts.has(channel)) input.value = String(c.value);
    stale(!output && staleAge(c), '');
  };
  const stale = (yes, why) => {
    el.dataset.stale = yes ? 'yes' : 'no';
    el.classList.toggle('stale', yes);
    if (ageEl && why) ageEl.textContent = why;
    for (const control of el.querySelectorAll('input, button')) control.disabled = yes && Boolean(why);
  };
  return { el, update, stale };
}

/**
 * Shows `channels` in `container`: the elements are made when the set of
 * channels is new (the first read), and updated in place after that.
 */
function show(container, channels, make) {
  const names = channels.map((c) => c.channel);
  if (!container.views || container.views.names.join(',') !== names.join(',')) {
    const views = new Map(names.map((name) => [name, make(name)]));
    container.views = { names, views };
    container.replaceChildren(...[...views.values()].map((v) => v.el));
  }
  for (const c of channels) container.views.views.get(c.channel).update(c);
}

let busy = false;
let readAgain = false;
/** Reads the channels; one read at a time, a read asked meanwhile runs after. */
async function refresh() {
  if (busy) {
    readAgain = true;
    return;
  }
  busy = true;
  try {
    // The node first: a stopped or offline one is not asked for its channels.
    const detail = await api(base);
    const running = detail.online !== false && (detail.nmt === 'operational' || detail.nmt === 'pre_operational');
    nodeState.dataset.nmt = detail.nmt;
    nodeState.dataset.online = String(detail.online !== false);
    nodeState.textContent = `Node ${node}: ${NMT[detail.nmt] || detail.nmt}, ${detail.online === false ? 'offline' : 'online'}`;
    if (!running) {
      const since = lastRead ? `last read ${clock(lastRead)}` : 'not read';
      markAll(true, `${detail.online === false ? 'offline' : `node ${NMT[detail.nmt] || detail.nmt}`}: ${since}`);
      root.dataset.loaded = 'true';
      return;
    }
    const io = await api(`${base}/io`);
    lastRead = Date.now();
    showMessage(pageMessage, '');
    show($('#digital-inputs'), io.digital_inputs, (name) => lamp(name, false));
    show($('#digital-outputs'), io.digital_outputs, (name) => lamp(name, true));
    show($('#analog-inputs'), io.analog_inputs, (name) => analog(name, false));
    show($('#analog-outputs'), io.analog_outputs, (name) => analog(name, true));
    root.dataset.loaded = 'true';
  } catch (error) {
    showMessage(pageMessage, `I/O: ${error.message}`);
    markAll(true, lastRead ? `not read since ${clock(lastRead)}` : 'not read');
  } finally {
    busy = false;
  }
  if (readAgain) {
    readAgain = false;
    refresh();
  }
}

refresh();
setInterval(refresh, POLL_MS);
// The connection indicator says whether the gateway is reachable, here too.
stream.connect();
