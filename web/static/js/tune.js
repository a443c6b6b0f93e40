// The tuning page of a UMC axis (/nodes/{bus}/{node}/axes/{axis}/tune):
// each loop's PID configuration (0x4021/0x4041/0x4061 + the axis offset,
// UMC manual §3.5.3) typed in human numbers and written as Q15.16, its
// live status (0x4020/0x4040/0x4060), a step test (POST .../step-test)
// drawn with its metrics, the last runs overlaid, and store (0x1010).

import { api, runAction } from './api.js';
import { $, clock, h, showMessage } from './dom.js';
import { stream } from './layout.js';

// Where a step's actual values came from (docs/rest-api.md, "Step test").
const SOURCES = { tpdo: 'from the TPDO', sdo: 'read by SDO', tpdo_then_sdo: 'TPDO, then SDO' };

const root = $('#tune-page');
const base = `/buses/${encodeURIComponent(root.dataset.bus)}/nodes/${encodeURIComponent(root.dataset.node)}`;
const axisBase = `${base}/axes/${encodeURIComponent(root.dataset.axis)}`;
const tabs = [...root.querySelectorAll('.loop-tab')];
const gainsResult = $('#gains-result');
const POLL_MS = 500;
const RUNS_KEPT = 4;

// Sub-indices 1..8 of a configuration record (§3.5.3).
const PARAMS = [
  { sub: 1, name: 'P', unit: (l) => `${l.outputUnit}/${l.inputUnit}` },
  { sub: 2, name: 'I', unit: (l) => `${l.outputUnit}/(${l.inputUnit}·s)` },
  { sub: 3, name: 'D', unit: (l) => `${l.outputUnit}·s/${l.inputUnit}` },
  { sub: 4, name: 'Min', unit: (l) => l.outputUnit },
  { sub: 5, name: 'Max', unit: (l) => l.outputUnit },
  { sub: 6, name: 'Threshold', unit: (l) => l.inputUnit },
  { sub: 7, name: 'Frequency_divider', unit: () => 'cycles', integer: true },
  { sub: 8, name: 'ANTI_REVERSE', unit: () => 'PID_flags b0', flag: true },
];

let loop = null;
const runs = [];

// Q15.16 saturates at the INTEGER32 range (Min and Max default to its ends).
const toQ = (v) => Math.max(-2147483648, Math.min(2147483647, Math.round(v * 65536)));
const fromQ = (raw) => raw / 65536;
const fmt = (v) => (Math.abs(v) >= 1000 ? v.toFixed(1) : +v.toPrecision(5));

function select(tab) {
  for (const t of tabs) t.setAttribute('aria-selected', String(t === tab));
  loop = { ...tab.dataset };
  $('#gains-object').textContent = loop.config;
  $('#status-object').textContent = loop.status;
  loadGains();
}

async function loadGains() {
  const body = $('#gains tbody');
  try {
    const entries = PARAMS.map((p) => [loop.config, p.sub]);
    const values = await api(`${base}/od/read`, { method: 'POST', body: { entries } });
    body.replaceChildren(...PARAMS.map((p, i) => {
      const raw = Number(values[i].value);
      const input = p.flag
        ? h('input', { type: 'checkbox', id: `gain-${p.sub}`, 'aria-label': p.name, checked: (raw & 1) === 1, dataset: { raw: String(raw) } })
        : h('input', { type: 'text', id: `gain-${p.sub}`, value: String(p.integer ? raw : fmt(fromQ(raw))), 'aria-label': p.name });
      const q = h('code', { class: 'q' }, p.integer || p.flag ? String(raw) : String(raw));
      if (!p.integer && !p.flag) input.addEventListener('input', () => { q.textContent = String(toQ(Number(input.value))); });
      // A check box is tapped through its label (a 44 px target).
      const field = p.flag ? h('label', { class: 'check' }, input, 'set') : input;
      return h('tr', { dataset: { sub: String(p.sub) } }, h('td', {}, p.name), h('td', {}, field), h('td', {}, p.unit(loop)), h('td', {}, q));
    }));
    root.dataset.loaded = 'true';
    showMessage($('#page-message'), '');
  } catch (err) {
    showMessage($('#page-message'), err.message);
  }
}

$('#gains-write').addEventListener('click', async (event) => {
  const writes = [];
  for (const p of PARAMS) {
    const input = $(`#gain-${p.sub}`);
    if (!input) continue;
    let value;
    if (p.flag) value = (Number(input.dataset.raw) & ~1) | (input.checked ? 1 : 0);
    else if (p.integer) value = Math.round(Number(input.value));
    else value = toQ(Number(input.value));
    if (!Number.isFinite(value)) {
      gainsResult.dataset.state = 'failed';
      gainsResult.textContent = `${p.name}: not a number.`;
      return;
    }
    writes.push([p, value]);
  }
  const done = await runAction(event.currentTarget, 'Writing…', async () => {
    for (const [p, value] of writes) await api(`${base}/od/${loop.config}/${p.sub}`, { method: 'PUT', body: { value } });
  });
  gainsResult.dataset.state = done.ok ? 'done' : 'failed';
  gainsResult.replaceChildren(done.ok
    ? h('strong', { id: 'gains-written', dataset: { loop: loop.loop } }, `The ${loop.loop} loop's gains are written (${clock()}).`)
    : `Not written: ${done.error.message}`);
  if (done.ok) loadGains();
});

$('#gains-store').addEventListener('click', async (event) => {
  const done = await runAction(event.currentTarget, 'Storing…', () => api(`${base}/store`, { method: 'POST', body: { what: 'all' } }));
  gainsResult.dataset.state = done.ok ? 'done' : 'failed';
  gainsResult.textContent = done.ok ? `Stored in the device (0x1010, ${clock()}).` : `Not stored: ${done.error.message}`;
});

let polling = false;
async function poll() {
  if (polling || !loop || document.hidden) return;
  polling = true;
  try {
    const entries = [1, 2, 3, 4].map((sub) => [loop.status, sub]);
    const values = await api(`${base}/od/read`, { method: 'POST', body: { entries } });
    const units = [loop.inputUnit, loop.inputUnit, loop.outputUnit, loop.outputUnit];
    ['input', 'error', 'integrator', 'output'].forEach((name, i) => {
      const v = values[i];
      $(`#st-${name}`).textContent = v.error ? '—' : `${fmt(fromQ(Number(v.value)))} ${units[i]}`;
    });
    $('#pid-status').dataset.live = 'true';
  } catch {
    // The next poll tries again; the page message is for actions.
  } finally {
    polling = false;
  }
}
setInterval(poll, POLL_MS);

function draw() {
  const canvas = $('#step-chart');
  const ctx = canvas.getContext('2d');
  const { width, height } = canvas;
  ctx.clearRect(0, 0, width, height);
  if (!runs.length) return;
  // Scaled to the response: the runs of the latest run's loop (another
  // loop's units would squash it), their target, peak and trough, and a
  // margin so that an overshoot is not drawn on the frame.
  const latestLoop = runs[runs.length - 1].loop;
  const shown = runs.filter((r) => r.loop === latestLoop);
  const all = shown.flatMap((r) => r.samples);
  const tMax = Math.max(...all.map((s) => s[0]), 1);
  let yMin = Math.min(...all.map((s) => Math.min(s[1], s[2])), ...shown.map((r) => r.from));
  let yMax = Math.max(...all.map((s) => Math.max(s[1], s[2])), ...shown.map((r) => r.from));
  if (yMax === yMin) { yMax += 1; yMin -= 1; }
  const margin = (yMax - yMin) * 0.05;
  yMax += margin;
  yMin -= margin;
  const pad = 40;
  const x = (t) => pad + (t / tMax) * (width - 2 * pad);
  const y = (v) => height - pad - ((v - yMin) / (yMax - yMin)) * (height - 2 * pad);
  ctx.strokeStyle = '#d8dee6';
  ctx.strokeRect(pad, pad, width - 2 * pad, height - 2 * pad);
  ctx.fillStyle = '#5f6b7a';
  ctx.font = '12px system-ui, sans-serif';
  ctx.fillText(String(fmt(yMax)), 2, pad);
  ctx.fillText(String(fmt(yMin)), 2, height - pad);
  ctx.fillText(`${fmt(tMax)} ms`, width - pad - 40, height - pad + 16);
  shown.forEach((run, i) => {
    const latest = i === shown.length - 1;
    ctx.lineWidth = latest ? 2 : 1;
    ctx.strokeStyle = latest ? '#1d3557' : `rgba(95, 107, 122, ${0.3 + 0.15 * i})`;
    ctx.beginPath();
    run.samples.forEach((s, j) => (j ? ctx.lineTo(x(s[0]), y(s[2])) : ctx.moveTo(x(s[0]), y(s[2]))));
    ctx.stroke();
  });
  const last = runs[runs.length - 1];
  ctx.strokeStyle = '#c8102e';
  ctx.setLineDash([5, 4]);
  ctx.beginPath();
  ctx.moveTo(x(0), y(last.to));
  ctx.lineTo(x(tMax), y(last.to));
  ctx.stroke();
  ctx.setLineDash([]);
}

const ms = (v) => (v === null || v === undefined ? '—' : `${fmt(v)} ms`);

$('#step-form').addEventListener('submit', async (event) => {
  event.preventDefault();
  const request = {
    loop: loop.loop,
    from: Number($('#step-from').value),
    to: Number($('#step-to').value),
    hold_ms: Number($('#step-hold').value),
    settle_band_pct: Number($('#step-band').value),
  };
  const metrics = $('#step-metrics');
  const done = await runAction($('#step-run'), 'Running…', () => api(`${axisBase}/step-test`, { method: 'POST', body: request }));
  if (!done.ok) {
    metrics.dataset.state = 'failed';
    metrics.textContent = `Step test failed (${clock()}): ${done.error.message}`;
    return;
  }
  const r = done.value;
  metrics.dataset.source = r.source;
  runs.push({ ...request, samples: r.samples });
  while (runs.length > RUNS_KEPT) runs.shift();
  metrics.dataset.state = 'done';
  metrics.dataset.rise = String(r.rise_time_ms);
  metrics.replaceChildren(
    h('span', {}, `Rise ${ms(r.rise_time_ms)}`),
    h('span', {}, `Overshoot ${fmt(r.overshoot_pct)} %`),
    h('span', {}, `Settling ${ms(r.settling_time_ms)}`),
    h('span', {}, `Steady-state error ${fmt(r.steady_state_error)}`),
    h('span', { class: 'sub', id: 'step-sampling', title: r.sampling_note }, `${r.samples.length} samples at ${fmt(r.sample_rate_hz)} Hz (${SOURCES[r.source] || r.source})`),
  );
  // Each run with the gains it ran with: the history compares tunings.
  const gains = r.gains ? ` (P ${fmt(r.gains.p)}, I ${fmt(r.gains.i)}, D ${fmt(r.gains.d)})` : '';
  $('#step-runs').prepend(h('li', {}, `${clock()} ${request.loop} ${request.from} → ${request.to}${gains}: rise ${ms(r.rise_time_ms)}, overshoot ${fmt(r.overshoot_pct)} %`));
  draw();
});

// Only a UMC has these loops (issue 31 point 6: a JMC's page opened full of
// NaN with Write and Store enabled): another node's page says so, and
// offers nothing to write.
async function start() {
  let detail;
  try {
    detail = await api(base);
  } catch (error) {
    showMessage($('#page-message'), `Node: ${error.message}`);
    return;
  }
  if (detail.profile !== 'umc') {
    root.dataset.tunable = 'no';
    showMessage($('#page-message'), `Node ${detail.id} is ${detail.name ? `a ${detail.name}` : 'no UMC'} (profile ${detail.profile}): it has no UMC control loops to tune.`);
    for (const control of root.querySelectorAll('button, input, select')) control.disabled = true;
    return;
  }
  root.dataset.tunable = 'yes';
  select(tabs.find((t) => t.dataset.loop === 'velocity') || tabs[0]);
  for (const tab of tabs) tab.addEventListener('click', () => select(tab));
  poll();
}

start();
// The connection indicator says whether the gateway is reachable, here too.
stream.connect();
