// The LED controller page (/nodes/{bus}/{node}/leds): one editor per
// segment of a UIO1LED (GET .../segments), applied with PUT
// .../segments/{n} carrying only the fields changed, and the editor then
// showing what the device answered when read back; and the live strip,
// drawn from the stream topic buses/{bus}/nodes/{id}/segments (the pixels
// the device shows now, rendered by the gateway from the parameters it
// read: see docs/websocket.md, "Value topics").

import { api, runAction } from './api.js';
import { $, clock, h, showMessage } from './dom.js';
import { stream } from './layout.js';

/** Preview samples a second asked of the stream: smooth enough for FLOW. */
const PREVIEW_RATE_HZ = 25;
/** Effects by API name, as the select lists them. */
const EFFECTS = [
  ['off', 'Off'], ['fix', 'Fixed'], ['flash', 'Flash'], ['breathing', 'Breathing'],
  ['flow', 'Flow'], ['flow_reversed', 'Flow reversed'],
];
/** The numeric fields: [key, label, min, max]. */
const NUMBERS = [
  ['led_count', 'LEDs', 0, 65535], ['speed', 'Speed', -32768, 32767], ['smooth', 'Smooth', 0, 65535],
  ['value', 'Value', -32768, 32767], ['min_value', 'Min', -32768, 32767], ['max_value', 'Max', -32768, 32767],
];
const CHANNELS = ['r', 'g', 'b', 'w'];

const pageEl = $('#leds-page');
const bus = pageEl.dataset.bus;
const nodeId = Number(pageEl.dataset.node);
const nodePath = `/buses/${encodeURIComponent(bus)}/nodes/${nodeId}`;
const topic = `buses/${bus}/nodes/${nodeId}/segments`;

const pageMessage = $('#page-message');
const container = $('#segments');
const stripCanvas = $('#strip');
const stripStatus = $('#strip-status');
const reloadButton = $('#reload');
const reloadResult = $('#reload-result');

const editors = new Map(); // segment number -> editor
let lastPreview = null;

const problems = new Map();
function problem(key, text) {
  if (text) problems.set(key, text);
  else problems.delete(key);
  showMessage(pageMessage, [...problems.values()].join(' · '));
}

// ---- colours -------------------------------------------------------------

const hex2 = (n) => n.toString(16).padStart(2, '0');
const rgbHex = (c) => `#${hex2(c.r)}${hex2(c.g)}${hex2(c.b)}`;

/** How an LED's red, green, blue and white look on a screen: the white
 * LED adds to every channel. */
function screenColor(c) {
  return `rgb(${Math.min(255, c.r + c.w)}, ${Math.min(255, c.g + c.w)}, ${Math.min(255, c.b + c.w)})`;
}

// ---- drawing the strip ---------------------------------------------------

/** Sizes a canvas's bitmap to its box (device pixels), once per change. */
function fitCanvas(canvas) {
  const ratio = window.devicePixelRatio || 1;
  const width = Math.max(1, Math.round(canvas.clientWidth * ratio));
  const height = Math.max(1, Math.round(canvas.clientHeight * ratio));
  if (canvas.width !== width || canvas.height !== height) {
    canvas.width = width;
    canvas.height = height;
  }
}

/** Draws `pixels` as a row of cells filling the canvas. */
function drawPixels(canvas, pixels) {
  fitCanvas(canvas);
  const ctx = canvas.getContext('2d');
  const { width, height } = canvas;
  ctx.fillStyle = '#11161d';
  ctx.fillRect(0, 0, width, height);
  canvas.dataset.leds = pixels.length;
  if (!pixels.length) return;
  const cell = width / pixels.length;
  // LEDs wide enough are drawn apart, as on a strip; the gap stays thin.
  const gap = cell >= 6 ? Math.min(3, Math.max(1, Math.floor(cell / 10))) : 0;
  for (let i = 0; i < pixels.length; i += 1) {
    const x0 = Math.round(i * cell);
    const x1 = Math.round((i + 1) * cell);
    ctx.fillStyle = screenColor(pixels[i]);
    ctx.fillRect(x0 + gap, gap, Math.max(1, x1 - x0 - 2 * gap), height - 2 * gap);
  }
}

function drawPreview(preview) {
  drawPixels(stripCanvas, preview.pixels);
  for (const seg of preview.segments) {
    const editor = editors.get(seg.segment);
    if (editor) drawPixels(editor.canvas, preview.pixels.slice(seg.start, seg.start + seg.led_count));
  }
}

let previewCount = 0;
let previewRateFrom = performance.now();
let previewRate = null;

stream.subscribe([topic], (data, message) => {
  if (!data) return;
  lastPreview = { ...data, ts: message.ts };
  previewCount += 1;
  if (data.error) {
    stripStatus.textContent = `Preview from the last parameters read: ${data.error}`;
    stripStatus.dataset.state = 'warn';
  } else {
    const now = performance.now();
    if (now - previewRateFrom >= 1000) {
      previewRate = (previewCount * 1000) / (now - previewRateFrom);
      previewCount = 0;
      previewRateFrom = now;
    }
    const rate = previewRate === null ? '' : ` · ${previewRate.toFixed(0)} frames/s`;
    stripStatus.textContent = `Live · ${data.led_count} LEDs${rate}`;
    stripStatus.dataset.state = 'live';
  }
  requestAnimationFrame(() => drawPreview(lastPreview));
  noticeChanges(data);
});

// ---- the editors ---------------------------------------------------------

function field(label, input, extra = null) {
  return h('label', { class: 'field' }, h('span', { class: 'label' }, label), input, extra);
}

function buildEditor(segment) {
  const n = segment.segment;
  const inputs = {};
  for (const [key, , min, max] of NUMBERS) {
    inputs[key] = h('input', { type: 'number', name: key, min, max, step: 1, inputmode: 'numeric', required: true });
  }
  inputs.effect = h('select', { name: 'effect' }, EFFECTS.map(([value, text]) => h('option', { value }, text)));
  inputs.dimmer = h('input', { type: 'range', name: 'dimmer', min: 0, max: 255, step: 1 });
  const dimmerText = h('output', { class: 'range-value' });
  inputs.colors = [0, 1, 2].map((i) => ({
    rgb: h('input', { type: 'color', name: `color${i + 1}`, 'aria-label': `Colour ${i + 1}` }),
    w: h('input', { type: 'range', name: `white${i + 1}`, min: 0, max: 255, step: 1, 'aria-label': `Colour ${i + 1} white` }),
    wText: h('output', { class: 'range-value' }),
    swatch: h('span', { class: 'swatch' }),
  }));
  const canvas = h('canvas', { class: 'segment-strip', height: 18, 'aria-label': `Segment ${n} as the device shows it now` });
  const summary = h('span', { class: 'summary-text' });
  const apply = h('button', { class: 'button primary', type: 'submit' }, 'Apply');
  const revert = h('button', { class: 'button', type: 'button' }, 'Revert');
  const result = h('span', { class: 'action-result', role: 'status', 'aria-live': 'polite' });
  const form = h('form', { class: 'segment-form', novalidate: true },
    h('div', { class: 'fields' },
      field('LEDs', inputs.led_count),
      field('Effect', inputs.effect),
      field('Dimmer', inputs.dimmer, dimmerText),
      field('Speed', inputs.speed),
      field('Smooth', inputs.smooth),
      field('Value', inputs.value),
      field('Min', inputs.min_value),
      field('Max', inputs.max_value)),
    h('div', { class: 'colors' }, inputs.colors.map((c, i) => h('div', { class: 'color' },
      h('span', { class: 'label' }, `Colour ${i + 1}`),
      h('div', { class: 'color-row' }, c.rgb, c.swatch),
      h('label', { class: 'white' }, h('span', {}, 'W'), c.w, c.wText)))),
    h('div', { class: 'actions' }, apply, revert, result));
  const card = h('details', { class: 'segment', dataset: { segment: n } },
    h('summary', {}, h('span', { class: 'segment-title' }, `Segment ${n}`), summary, canvas),
    form);
  const editor = { n, card, form, inputs, canvas, summary, apply, revert, result, dimmerText, read: null, busy: false };

  const refreshMarks = () => {
    dimmerText.textContent = `${Math.round((inputs.dimmer.value / 255) * 100)} %`;
    for (const c of inputs.colors) {
      c.wText.textContent = c.w.value;
      c.swatch.style.background = screenColor({ ...rgbOf(c.rgb.value), w: Number(c.w.value) });
    }
    const changed = changes(editor);
    form.dataset.dirty = String(Object.keys(changed.body).length > 0);
    for (const el of form.querySelectorAll('[data-changed]')) delete el.dataset.changed;
    for (const el of changed.fields) el.dataset.changed = 'true';
  };
  editor.refreshMarks = refreshMarks;
  form.addEventListener('input', refreshMarks);
  form.addEventListener('submit', (event) => {
    event.preventDefault();
    applyEditor(editor);
  });
  revert.addEventListener('click', () => {
    fill(editor, editor.read);
    result.textContent = '';
  });
  return editor;
}

function rgbOf(text) {
  return { r: parseInt(text.slice(1, 3), 16), g: parseInt(text.slice(3, 5), 16), b: parseInt(text.slice(5, 7), 16) };
}

const effectName = (effect) => (EFFECTS.find(([value]) => value === effect) || [effect, effect])[1];

/** Puts what the device answered into the editor. */
function fill(editor, segment) {
  editor.read = segment;
  const { inputs } = editor;
  for (const [key] of NUMBERS) inputs[key].value = String(segment[key]);
  if (![...inputs.effect.options].some((o) => o.value === segment.effect)) {
    // A value the manual does not define: shown as the device has it.
    inputs.effect.append(h('option', { value: segment.effect }, `Unknown ${segment.effect}`));
  }
  inputs.effect.value = segment.effect;
  inputs.dimmer.value = String(segment.dimmer);
  segment.colors.forEach((color, i) => {
    inputs.colors[i].rgb.value = rgbHex(color);
    inputs.colors[i].w.value = String(color.w);
  });
  editor.summary.textContent = segment.led_count
    ? `${segment.led_count} LEDs · ${effectName(segment.effect)}`
    : 'no LEDs';
  editor.card.dataset.effect = segment.effect;
  editor.card.dataset.ledCount = segment.led_count;
  editor.refreshMarks();
}

/** What the editor changed against what was read: the PUT body, and the
 * inputs that differ. Colours carry only their changed channels. */
function changes(editor) {
  const { inputs, read } = editor;
  const body = {};
  const fields = [];
  if (!read) return { body, fields, errors: [] };
  const errors = [];
  for (const [key, label, min, max] of NUMBERS) {
    const text = inputs[key].value.trim();
    const value = Number(text);
    if (text === '' || !Number.isInteger(value) || value < min || value > max) {
      if (String(read[key]) !== text) {
        errors.push(`${label} must be a whole number from ${min} to ${max}`);
        fields.push(inputs[key]);
      }
      continue;
    }
    if (value !== read[key]) {
      body[key] = value;
      fields.push(inputs[key]);
    }
  }
  if (inputs.effect.value !== read.effect) {
    body.effect = inputs.effect.value;
    fields.push(inputs.effect);
  }
  if (Number(inputs.dimmer.value) !== read.dimmer) {
    body.dimmer = Number(inputs.dimmer.value);
    fields.push(inputs.dimmer);
  }
  const colors = inputs.colors.map((c, i) => {
    const now = { ...rgbOf(c.rgb.value), w: Number(c.w.value) };
    const delta = {};
    for (const ch of CHANNELS) if (now[ch] !== read.colors[i][ch]) delta[ch] = now[ch];
    if (!Object.keys(delta).length) return null;
    if ('w' in delta) fields.push(c.w);
    if (Object.keys(delta).some((ch) => ch !== 'w')) fields.push(c.rgb);
    return delta;
  });
  while (colors.length && colors[colors.length - 1] === null) colors.pop();
  if (colors.length) body.colors = colors;
  return { body, fields, errors };
}

const FIELD_NAMES = {
  led_count: 'LEDs', effect: 'effect', dimmer: 'dimmer', speed: 'speed', smooth: 'smooth',
  value: 'value', min_value: 'min', max_value: 'max',
};

function describeBody(body) {
  const names = Object.keys(body).filter((k) => k !== 'colors').map((k) => FIELD_NAMES[k] || k);
  (body.colors || []).forEach((c, i) => { if (c) names.push(`colour ${i + 1}`); });
  return names.join(', ');
}

async function applyEditor(editor) {
  const { body, errors } = changes(editor);
  if (errors.length) {
    editor.result.dataset.state = 'failed';
    editor.result.textContent = errors.join('; ');
    return;
  }
  if (!Object.keys(body).length) {
    editor.result.dataset.state = 'done';
    editor.result.textContent = 'Nothing changed to apply.';
    return;
  }
  editor.busy = true;
  editor.result.dataset.state = 'busy';
  editor.result.textContent = `Writing ${describeBody(body)}…`;
  const result = await runAction(editor.apply, 'Applying…',
    () => api(`${nodePath}/segments/${editor.n}`, { method: 'PUT', body }));
  editor.busy = false;
  if (result.ok) {
    // What the device has now, read back after the writes.
    fill(editor, result.value);
    editor.result.dataset.state = 'done';
    editor.result.textContent = `Applied ${describeBody(body)} (${clock()}); showing the values read back.`;
  } else {
    editor.result.dataset.state = 'failed';
    editor.result.textContent = `Not applied (${clock()}): ${result.error.message}`;
    // Part of it may have been written: show what the device has.
    reloadSegment(editor);
  }
}

async function reloadSegment(editor) {
  try {
    const all = await api(`${nodePath}/segments`);
    const segment = all.find((s) => s.segment === editor.n);
    if (segment) fill(editor, segment);
  } catch (error) {
    problem('segments', `Segments: ${error.message}`);
  }
}

/** Reads every segment; editors with unapplied changes keep them. */
async function loadSegments() {
  let list;
  try {
    list = await api(`${nodePath}/segments`);
  } catch (error) {
    problem('segments', `Segments of node ${nodeId}: ${error.message}`);
    if (!editors.size) container.replaceChildren(h('p', { class: 'placeholder' }, 'The segments could not be read.'));
    return false;
  }
  problem('segments', null);
  if (!editors.size) {
    container.replaceChildren();
    for (const segment of list) {
      const editor = buildEditor(segment);
      editors.set(segment.segment, editor);
      container.append(editor.card);
      fill(editor, segment);
      editor.card.open = segment.led_count > 0 || segment.segment === 1;
    }
    if (lastPreview) drawPreview(lastPreview);
  } else {
    for (const segment of list) {
      const editor = editors.get(segment.segment);
      if (editor && !editor.busy && editor.form.dataset.dirty !== 'true') fill(editor, segment);
    }
  }
  return true;
}

// Someone else (another client, a script) changed the LED count or the
// effect: the preview says so first, and the editors read them again.
let rereadAt = 0;
function noticeChanges(preview) {
  if (!preview.segments || performance.now() - rereadAt < 2000) return;
  const differs = preview.segments.some((seg) => {
    const editor = editors.get(seg.segment);
    return editor && editor.read && !editor.busy
      && (editor.read.led_count !== seg.led_count || editor.read.effect !== seg.effect);
  });
  if (differs) {
    rereadAt = performance.now();
    loadSegments();
  }
}

async function loadNode() {
  try {
    const nodes = await api(`/buses/${encodeURIComponent(bus)}/nodes`);
    const node = nodes.find((n) => n.id === nodeId);
    if (!node) {
      problem('node', `Node ${nodeId} is not known on bus ${bus}.`);
      return;
    }
    problem('node', null);
    $('#node-name').textContent = [node.name, node.nmt && node.nmt.replace('_', '-'), node.online ? 'online' : 'offline']
      .filter(Boolean).join(' · ');
  } catch (error) {
    problem('node', `Node ${nodeId}: ${error.message}`);
  }
}

reloadButton.addEventListener('click', async () => {
  reloadResult.dataset.state = 'busy';
  reloadResult.textContent = 'Reading every segment…';
  const result = await runAction(reloadButton, 'Reading…', loadSegments);
  const ok = result.ok && result.value;
  reloadResult.dataset.state = ok ? 'done' : 'failed';
  reloadResult.textContent = ok ? `Read at ${clock()}` : 'Reading failed (see above)';
});

window.addEventListener('resize', () => { if (lastPreview) drawPreview(lastPreview); });

stream.onState(({ state, reconnected, error }) => {
  if (error) {
    problem('stream', `Live strip: ${error}`);
    return;
  }
  if (state === 'connected') {
    problem('stream', null);
    // The rate for the preview (stream.js subscribes without one).
    stream.send({ op: 'subscribe', topics: [topic], max_rate_hz: PREVIEW_RATE_HZ });
    if (reconnected) {
      loadNode();
      loadSegments();
    }
  } else if (state === 'disconnected') {
    stripStatus.textContent = 'Disconnected: the strip shows the last preview received';
    stripStatus.dataset.state = 'warn';
  }
});

// For tests and the curious: the last preview the stream brought.
window.candeckLeds = { lastPreview: () => lastPreview };

stream.connect();
loadNode();
loadSegments();
