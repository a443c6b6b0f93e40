// The overview's "Unconfigured devices (LSS)" panel: Fastscan of one bus
// for devices without a node ID (POST /buses/{bus}/lss/scan), and a node
// ID given to one of them (POST /buses/{bus}/lss/configure, admin). A
// device configured boots up and shows in the node list through the stream.

import { api, runAction } from './api.js';
import { $, clock, h } from './dom.js';

const busSelect = $('#lss-bus');
const scanButton = $('#lss-scan');
const storeBox = $('#lss-store');
const foundBody = $('#lss-found tbody');
const resultEl = $('#lss-result');

const hex = (n) => `0x${Number(n).toString(16).toUpperCase().padStart(8, '0')}`;

function result(state, ...children) {
  resultEl.dataset.state = state;
  resultEl.replaceChildren(...children.filter(Boolean));
}

async function loadBuses() {
  try {
    const list = await api('/buses');
    busSelect.replaceChildren(...list.map((bus) => h('option', { value: bus.name }, bus.name)));
  } catch (error) {
    result('failed', `Buses: ${error.message}`);
  }
}

function placeholder(text) {
  foundBody.replaceChildren(h('tr', { class: 'placeholder' }, h('td', { colspan: 5 }, text)));
}

function row(bus, device) {
  const input = h('input', { type: 'number', min: 1, max: 127, required: true, 'aria-label': `Node ID for serial ${hex(device.serial)}` });
  const button = h('button', { type: 'submit', class: 'lss-assign' }, 'Assign');
  const form = h('form', { class: 'lss-assign-form' }, input, button);
  form.addEventListener('submit', async (event) => {
    event.preventDefault();
    const nodeId = Number(input.value);
    result('busy', `Giving node ID ${nodeId} to serial ${hex(device.serial)}…`);
    const done = await runAction(button, 'Assigning…', () => api(`/buses/${encodeURIComponent(bus)}/lss/configure`, {
      method: 'POST', body: { ...device, node_id: nodeId, store: storeBox.checked },
    }));
    if (!done.ok) {
      result('failed', h('strong', {}, `Assign failed (${clock()}): `), done.error.message);
      return;
    }
    const href = `/nodes/${encodeURIComponent(bus)}/${done.value.id}`;
    result('done', h('strong', {}, `The device booted up as node ${done.value.id} (${clock()}). `),
      h('a', { href }, `Open node ${done.value.id}`));
    form.closest('tr').remove();
    if (!foundBody.children.length) placeholder('Every device found has a node ID now.');
  });
  return h('tr', { dataset: { serial: device.serial } },
    h('td', { 'data-label': 'Vendor' }, h('code', {}, hex(device.vendor_id))),
    h('td', { 'data-label': 'Product' }, h('code', {}, hex(device.product_code))),
    h('td', { 'data-label': 'Revision' }, h('code', {}, hex(device.revision))),
    h('td', { 'data-label': 'Serial' }, h('code', {}, hex(device.serial))),
    h('td', { 'data-label': 'Node ID' }, form));
}

scanButton.addEventListener('click', async () => {
  const bus = busSelect.value;
  if (!bus) return;
  result('busy', `Scanning bus ${bus}…`);
  const done = await runAction(scanButton, 'Scanning…', () => api(`/buses/${encodeURIComponent(bus)}/lss/scan`, { method: 'POST', body: {} }));
  if (!done.ok) {
    result('failed', h('strong', {}, `Scan failed (${clock()}): `), done.error.message);
    return;
  }
  const { found } = done.value;
  result('done', `${found.length} unconfigured device${found.length === 1 ? '' : 's'} on bus ${bus} (${clock()}).`);
  if (found.length === 0) placeholder(`No device without a node ID on bus ${bus}.`);
  else foundBody.replaceChildren(...found.map((device) => row(bus, device)));
});

loadBuses();
