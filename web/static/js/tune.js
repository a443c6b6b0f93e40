// The tuning page of a UMC axis (/nodes/{bus}/{node}/axes/{axis}/tune):
// each loop's PID configuration (0x4021/0x4041/0x4061 + the axis offset,
// UMC manual §3.5.3) typed in human numbers and written as Q15.16, its
// live status (0x4020/0x4040/0x4060), a step test (POST .../step-test)
// drawn with its metrics (stepchart.js: scaled to the response, the
// earlier runs of the same step overlaid), the runs listed with the gains
// each ran with and kept in this browser's local storage, and store
// (0x1010).

import { api, runAction } from './api.js';
import { $, clock, h, showMessage } from './dom.js';
import { stream } from './layout.js';
import { colourOf, comparable, drawStep } from './stepchart.js';

// Where a step's actual values came from (docs/rest-api.md, "Step test").
const SOURCES = { tpdo: 'from the TPDO', sdo: 'read by SDO', tpdo_then_sdo: 'TPDO, then SDO' };

const root = $('#tune-page');
const base = `/buses/${encodeURIComponent(root.dataset.bus)}/nodes/${encodeURIComponent(root.dataset.node)}`;
const axisBase = `${base}/axes/${encodeURIComponent(root.dataset.axis)}`;
const tabs = [...root.querySelectorAll('.loop-tab')];
const gainsResult = $('#gains-result');
const POLL_MS = 500;
// The runs listed (and stored), newest first.
const RUNS_KEPT = 10;
// The run history of this axis, in this browser's local storage: it is
// the browser's record of what it ran (the gateway keeps no step results),
// so a reload keeps it and another browser has its own.
const RUNS_KEY = `candeck.tune.runs:${root.dataset.bus}/${root.dataset.node}/${root.dataset.axis}`;

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
// Oldest first.
const runs = loadRuns();
// The step's unit per loop, from the axis's units (GET .../axes/{axis}).
const stepUnits = { torque: '‰ of rated torque', velocity: 'velocity units', position: 'position units' };

// Q15.16 saturates at the INTEGER32 range (Min and Max default to its ends).
const toQ = (v) => Math.max(-2147483648, Math.min(2147483647, Math.round(v * 65536)));
const fromQ = (raw) => raw / 65536;
const fmt = (v) => (Math.abs(v) >= 1000 ? v.toFixed(1) : +v.toPrecision(5));

function select(tab) {
  for (const t of tabs) t.setAttribute('aria-selected', String(t === tab));
  loop = { ...tab.dataset };
  $('#gains-object').textContent = loop.config;
  $('#status-object').textContent = loop.status;
  $('#step-unit').textContent = stepUnits[loop.loop] || '';
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
  // The run as the gateway answered it, with the gains the drive had
  // when it started (null where they could not be read).
  runs.push({
    ...request,
    at: Date.now(),
    unit: stepUnits[request.loop],
    gains: r.gains || null,
    rise_time_ms: r.rise_time_ms,
    overshoot_pct: r.overshoot_pct,
    settling_time_ms: r.settling_time_ms,
    steady_state_error: r.steady_state_error,
    samples: r.samples,
  });
  while (runs.length > RUNS_KEPT) runs.shift();
  saveRuns();
  metrics.dataset.state = 'done';
  metrics.dataset.rise = String(r.rise_time_ms);
  metrics.replaceChildren(
    h('span', {}, `Rise ${ms(r.rise_time_ms)}`),
    h('span', {}, `Overshoot ${fmt(r.overshoot_pct)} %`),
    h('span', {}, `Settling ${ms(r.settling_time_ms)}`),
    h('span', {}, `Steady-state error ${fmt(r.steady_state_error)}`),
    h('span', { class: 'sub', id: 'step-sampling', title: r.sampling_note }, `${r.samples.length} samples at ${fmt(r.sample_rate_hz)} Hz (${SOURCES[r.source] || r.source})`),
  );
  showRuns();
});

// A stored run is used only as the page stores it: anything else (another
// version's, edited by hand) is left out rather than drawn wrong.
function isRun(r) {
  const finite = (v) => typeof v === 'number' && Number.isFinite(v);
  return r && typeof r === 'object' && typeof r.loop === 'string' && finite(r.from) && finite(r.to) && finite(r.at)
    && Array.isArray(r.samples) && r.samples.every((s) => Array.isArray(s) && s.length === 3 && s.every(finite))
    && (r.gains === null || (typeof r.gains === 'object' && ['p', 'i', 'd'].every((k) => finite(r.gains[k]))));
}

function loadRuns() {
  try {
    const stored = JSON.parse(localStorage.getItem(RUNS_KEY) || '[]');
    return Array.isArray(stored) ? stored.filter(isRun).slice(-RUNS_KEPT) : [];
  } catch {
    return [];
  }
}

// Local storage holds a few megabytes: when the runs' samples do not fit,
// the older runs are kept without them (listed, no longer drawn).
function saveRuns() {
  for (let keepSamples = runs.length; keepSamples >= 0; keepSamples -= 1) {
    const from = runs.length - keepSamples;
    try {
      localStorage.setItem(RUNS_KEY, JSON.stringify(runs.map((r, i) => (i < from ? { ...r, samples: [] } : r))));
      return;
    } catch {
      // Too large (or storage off): try with fewer samples.
    }
  }
}

// The run list, newest first, and the chart of the latest run with the
// earlier runs of the same step.
function showRuns() {
  const drawn = comparable(runs);
  const latest = runs[runs.length - 1];
  drawStep($('#step-chart'), drawn, latest ? latest.unit : '');
  const gain = (g, k) => (g ? fmt(g[k]) : '—');
  $('#step-runs tbody').replaceChildren(...runs.slice().reverse().map((r) => {
    const colour = colourOf(r, drawn);
    const swatch = colour ? h('span', { class: 'swatch', style: `background: ${colour}`, title: 'drawn in this colour' }) : '';
    return h('tr', {
      dataset: {
        loop: r.loop,
        from: String(r.from),
        to: String(r.to),
        p: r.gains ? String(r.gains.p) : '',
        i: r.gains ? String(r.gains.i) : '',
        d: r.gains ? String(r.gains.d) : '',
        rise: String(r.rise_time_ms),
        overshoot: String(r.overshoot_pct),
        drawn: String(Boolean(colour)),
      },
    },
    h('td', {}, swatch),
    h('td', {}, clock(r.at)),
    h('td', {}, r.loop),
    h('td', {}, `${r.from} → ${r.to} ${r.unit || ''}`),
    h('td', { class: 'num' }, gain(r.gains, 'p')),
    h('td', { class: 'num' }, gain(r.gains, 'i')),
    h('td', { class: 'num' }, gain(r.gains, 'd')),
    h('td', { class: 'num' }, ms(r.rise_time_ms)),
    h('td', { class: 'num' }, `${fmt(r.overshoot_pct)} %`),
    h('td', { class: 'num' }, ms(r.settling_time_ms)),
    h('td', { class: 'num' }, String(fmt(r.steady_state_error))));
  }));
  $('#runs-clear').disabled = !runs.length;
}

$('#runs-clear').addEventListener('click', () => {
  runs.length = 0;
  localStorage.removeItem(RUNS_KEY);
  showRuns();
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
  // The units the step's levels are in (the axis's, as its manual has
  // them): the chart's and the run list's.
  try {
    const units = (await api(axisBase)).units || {};
    Object.assign(stepUnits, {
      torque: units.torque || stepUnits.torque,
      velocity: units.vl_velocity || units.velocity || stepUnits.velocity,
      position: units.position || stepUnits.position,
    });
  } catch (error) {
    showMessage($('#page-message'), `Axis: ${error.message}`);
  }
  showRuns();
  select(tabs.find((t) => t.dataset.loop === 'velocity') || tabs[0]);
  for (const tab of tabs) tab.addEventListener('click', () => select(tab));
  poll();
}

start();
// The connection indicator says whether the gateway is reachable, here too.
stream.connect();
