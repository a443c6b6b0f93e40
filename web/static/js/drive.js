// The drive page of one axis (/nodes/{bus}/{node}/axes/{axis}): the CiA 402
// state diagram with the transitions that can be commanded from the state
// the drive reports, fault and its last EMCY with fault reset, halt, the
// motion forms of the modes the axis supports, the statusword decoded and
// live charts of position, velocity and torque.
//
// Everything shown is what the device said: the axis topic of the stream
// (20 samples a second) and the answers of the actions, which the gateway
// reads back from the drive. What a form sent is never shown as the
// drive's value. After the stream comes back (the gateway restarted) the
// axis and the node are read again over REST.

import { api, runAction } from './api.js';
import { axisFault } from './axes.js';
import { TimeChart } from './chart.js';
import { commandable, isFault, stateDiagram, stateLabel, statuswordBits } from './cia402.js';
import { $, clock, h, markAge, showMessage } from './dom.js';
import { stream } from './layout.js';
import { MODE_LABELS, clipText, motionForm, unitsOf } from './motion.js';

const RATE_HZ = 20;
// A value older than this is shown stale (greyed, with its age): the axis
// topic is asked at RATE_HZ, but the gateway reads it in the node's SDO
// queue (at most --axis-poll-hz, shared with everyone) or from TPDOs, so
// its period is not known here: 2 s, many periods of any of them.
const STALE_MS = 2000;
// The device's 0x6061 names by the move mode whose form they belong to.
const MOVE_MODE_OF = {
  profile_position: 'profile_position', velocity: 'velocity', profile_velocity: 'velocity',
  torque: 'torque', profile_torque: 'torque', duty_cycle: 'duty_cycle',
  continuous_position: 'continuous_position', interpolated_position: 'interpolated_position', homing: 'homing',
};

/** The mode the drive displays (0x6061), in words. */
function modeName({ mode, mode_raw: raw }) {
  if (mode) return mode === 'velocity' ? 'Velocity (VL)' : (MODE_LABELS[mode] || mode.replaceAll('_', ' ').replace(/^./, (c) => c.toUpperCase()));
  return raw === null || raw === undefined ? '—' : `Mode ${raw}`;
}

const root = $('#drive');
const bus = root.dataset.bus;
const nodeText = root.dataset.node;
const axisText = root.dataset.axis;
const nodePath = `/buses/${encodeURIComponent(bus)}/nodes/${encodeURIComponent(nodeText)}`;
const axisPath = `${nodePath}/axes/${encodeURIComponent(axisText)}`;

const pageMessage = $('#page-message');
const body = $('#drive-body');
const stateBadge = $('#state-badge');
const transitionList = $('#transitions');
const stateResult = $('#state-result');
const faultPanel = $('#fault-panel');
const faultTitle = $('#fault-title');
const faultEmcy = $('#fault-emcy');
const faultReset = $('#fault-reset');
const faultResult = $('#fault-result');
const haltOn = $('#halt-on');
const quickHalt = $('#quick-halt');
const quickStop = $('#quick-stop');
const quickResult = $('#quick-result');
const haltOff = $('#halt-off');
const modeTabs = $('#mode-tabs');
const motionHost = $('#motion-form');
const moveResult = $('#move-result');
const moveGate = $('#move-gate');
const bitsList = $('#status-bits');
const liveNote = $('#live-note');

const updateDiagram = stateDiagram($('#diagram'));
const charts = {
  position: new TimeChart($('#chart-position'), { color: '#1d3557' }),
  velocity: new TimeChart($('#chart-velocity'), { color: '#2a7f62' }),
  torque: new TimeChart($('#chart-torque'), { color: '#b5541c' }),
};

let detail = null; // GET node: name, profile, emcy
let status = null; // the newest axis status read from the device
let supported = null; // the move modes of the axis (GET axis)
let axisInfo = {}; // the axis's units and limits (GET axis)
let selectedMode = null;
let acting = false; // a state, fault or halt action is running
let moveButtons = [];
let unsubscribe = null;
let fatal = false;
const problems = new Map();

function problem(key, text) {
  if (text) problems.set(key, text);
  else problems.delete(key);
  if (!fatal) showMessage(pageMessage, [...problems.values()].join(' · '));
}

const show = (value) => (value === null || value === undefined ? '—' : Number(value).toLocaleString('en-US'));

/** An action's outcome in `el`: busy, done or failed, with the time. */
function result(el, state, ...content) {
  el.dataset.state = state;
  el.replaceChildren(...content);
}
const say = result;

// ---- loading -----------------------------------------------------------------

/** The page cannot show this axis at all (unknown bus, node or axis). */
function giveUp(error) {
  fatal = true;
  body.hidden = true;
  $('#drive-stops').hidden = true;
  faultPanel.hidden = true;
  stateBadge.hidden = true;
  showMessage(pageMessage, `This axis cannot be shown: ${error.message}`);
  pageMessage.dataset.code = error.code;
}

const NOT_THERE = new Set(['unknown_bus', 'unknown_node', 'unknown_axis', 'not_a_drive', 'invalid_request']);

let loading = null;

/** Reads the node and the axis over REST (at start and after a reconnect). */
function load() {
  if (!loading) loading = loadOnce().finally(() => { loading = null; });
  return loading;
}

async function loadOnce() {
  let node;
  let axis;
  try {
    [node, axis] = await Promise.all([api(nodePath), api(axisPath)]);
  } catch (error) {
    if (NOT_THERE.has(error.code)) giveUp(error);
    else problem('load', `Reading the axis: ${error.message}`);
    return;
  }
  problem('load', null);
  detail = node;
  supported = axis.supported_modes;
  axisInfo = { units: axis.units, limits: axis.limits };
  renderUnits();
  renderNode();
  renderModes();
  applyStatus(axis);
  if (!unsubscribe) {
    // The topic by the canonical numbers the gateway answered with.
    unsubscribe = stream.subscribe([`buses/${bus}/nodes/${node.id}/axes/${axis.axis}`], onSample);
    askRate();
  }
}

async function reloadNode() {
  try {
    detail = await api(nodePath);
    problem('node', null);
  } catch (error) {
    problem('node', `Reading the node: ${error.message}`);
    return;
  }
  renderNode();
  renderFault();
}

// The stream asks the rate of the page's first subscribe; this page wants
// its charts at RATE_HZ: the same topic subscribed again with the rate
// replaces the first (docs/websocket.md).
function askRate() {
  if (!unsubscribe || stream.state !== 'connected') return;
  stream.send({ op: 'subscribe', topics: [`buses/${bus}/nodes/${detail.id}/axes/${status.axis}`], max_rate_hz: RATE_HZ });
}

// ---- the node ---------------------------------------------------------------

function renderNode() {
  const name = detail.name || `Node ${detail.id}`;
  $('#node-name').textContent = name;
  $('#node-link').textContent = `Node ${detail.id}`;
  $('#node-product').textContent = `${detail.profile}${detail.online === false ? ' · offline' : ''}`;
  // Tuning only where the profile has control loops: the UMC's.
  $('#tune-link').hidden = detail.profile !== 'umc';
  document.title = `Axis ${axisText} · ${name} · candeck`;
  renderTabs();
}

/** The node's axes as tabs, each with its own fault mark: this axis's
 * from its live status, the others' from the node as last read. */
let tabsDrawn = ''; // what the tabs show: redrawn only when it changes (a tab replaced under a finger loses its tap)

function renderTabs() {
  const axes = (detail.axes ? detail.axes : [{ axis: Number(axisText) }]).map((a) => {
    const current = String(a.axis) === String(Number(axisText));
    return { a, current, ...axisFault(detail, current && status ? status : a) };
  });
  const drawn = JSON.stringify(axes.map(({ a, faulted, cause }) => [a.axis, faulted, cause && cause.timestamp_us]));
  if (drawn === tabsDrawn) return;
  tabsDrawn = drawn;
  $('#axis-tabs').replaceChildren(...axes.map(({ a, current, faulted, cause }) => {
    return h('a', {
      href: `/nodes/${encodeURIComponent(bus)}/${detail.id}/axes/${a.axis}`,
      'aria-current': current ? 'page' : null,
      dataset: { axis: a.axis, fault: faulted ? 'yes' : 'no' },
      title: faulted ? `Axis ${a.axis} in fault${cause ? `: ${cause.code} ${cause.text}` : ''}` : null,
    }, `Axis ${a.axis}`, faulted ? h('span', { class: 'fault-mark', 'aria-label': ' (fault)' }, ' ⚠') : null);
  }));
}

function renderFault() {
  const { faulted, cause, last } = axisFault(detail, status);
  faultPanel.dataset.fault = faulted ? 'yes' : 'no';
  faultTitle.textContent = !faulted ? 'No fault'
    : status.state === 'fault' ? 'FAULT' : `FAULT · ${stateLabel(status.state).toLowerCase()}`;
  // In fault: the axis's own cause (its newest EMCY that is not a reset);
  // otherwise its newest EMCY, whatever it says.
  const emcy = faulted ? cause : last;
  const axisNo = status ? status.axis : Number(axisText);
  faultEmcy.replaceChildren(emcy
    ? h('span', {}, faulted ? 'Cause: ' : `Last EMCY of axis ${axisNo}: `,
      h('code', { class: emcy.code === '0x0000' ? 'cleared' : null }, emcy.code), ' ', emcy.text,
      h('span', { class: 'sub' }, emcy.axis ? ` · EMCY of axis ${emcy.axis}` : ' · EMCY of the node',
        ` · error register 0x${emcy.register.toString(16).padStart(2, '0').toUpperCase()}`,
        ` · ${clock(emcy.timestamp_us / 1000)}`))
    : h('span', { class: 'sub' }, !detail ? '…' : faulted ? 'Cause unknown: no EMCY from this axis.' : 'No EMCY from this axis.'));
  faultReset.classList.toggle('urgent', Boolean(faulted));
  // A reset with no fault does nothing: offered only in fault.
  if (!faultReset.hasAttribute('aria-busy')) faultReset.disabled = acting || !faulted;
  if (detail) renderTabs();
}

// ---- the axis status --------------------------------------------------------

function onSample(data, message) {
  if (message.lagged) return;
  for (const [key, chart] of Object.entries(charts)) chart.push(data.error ? null : data[key]);
  if (data.state === null && !data.error) return; // nothing read yet
  applyStatus(data);
}

// When the newest value the device gave arrived (REST or stream); a
// sample with an error repeats the last values and does not count.
let readAt = null;

function renderAges() {
  if (readAt === null) return;
  const age = Date.now() - readAt;
  for (const readout of document.querySelectorAll('#live-panel .readout[data-live]')) {
    markAge(readout, readout.querySelector('.age'), age, STALE_MS);
  }
  markAge($('#status-panel'), $('#statusword-age'), age, STALE_MS);
}
setInterval(renderAges, 250);

/** Shows a status the gateway read from the drive (REST or stream). */
function applyStatus(next) {
  status = { ...status, ...next };
  if (next.state !== undefined && !next.error) {
    readAt = Date.now();
    renderAges();
  }
  const { state } = status;
  // Out of operation enabled nothing moves, and the gateway ended the lease.
  if (lease && state && state !== 'operation_enabled') dropLease(null);
  stateBadge.textContent = stateLabel(state);
  stateBadge.dataset.state = state || '';
  root.dataset.state = state || '';
  const available = commandable(state);
  updateDiagram(state, available);
  if (!acting) renderTransitions(available);
  renderFault();

  $('#value-position').textContent = show(status.position);
  $('#value-velocity').textContent = show(status.velocity);
  renderConversions();
  $('#value-torque').textContent = show(status.torque);
  $('#value-mode').textContent = modeName(status);
  const reached = $('#target-reached');
  reached.dataset.on = status.target_reached === true ? 'yes' : 'no';
  reached.textContent = status.target_reached === true ? 'Target reached'
    : status.target_reached === false ? 'Target not reached' : 'Target —';
  $('#value-source').textContent = status.source === 'tpdo' ? 'from TPDOs' : status.source === 'sdo' ? 'polled over SDO' : 'read over REST';
  if (next.error) {
    liveNote.hidden = false;
    liveNote.textContent = `Not updated: ${next.error}. The values are the last ones read.`;
  } else if (next.source) {
    liveNote.hidden = true;
  }

  const word = status.statusword;
  $('#statusword-hex').textContent = word === null || word === undefined ? '—'
    : `0x${word.toString(16).padStart(4, '0').toUpperCase()}`;
  bitsList.replaceChildren(...statuswordBits(word, status.mode).map((bit) => h('li', {
    class: 'bit', dataset: { bit: bit.bit, on: bit.on === null ? 'unknown' : bit.on ? 'yes' : 'no' }, title: bit.title,
  }, h('span', { class: 'bit-n' }, String(bit.bit)), bit.name)));

  const enabled = state === 'operation_enabled';
  for (const button of moveButtons) if (button.dataset.state !== 'busy' && !button.hasAttribute('aria-busy')) button.disabled = !enabled;
  moveGate.hidden = enabled;
  moveGate.textContent = `Moves need operation enabled; the drive is in ${stateLabel(state).toLowerCase()}.`;
  for (const button of [haltOn, haltOff]) if (!button.hasAttribute('aria-busy')) button.disabled = acting || !enabled;
  // The bar kept in view: never disabled by another action running, a stop goes out at once.
  for (const button of [quickHalt, quickStop]) if (!button.hasAttribute('aria-busy')) button.disabled = !enabled;
}

// ---- units and limits -----------------------------------------------------------
//
// What the drive's numbers count, from its product's manual (the gateway's
// profiles), and the limits it applies to requests, as read with the axis.

const units = () => unitsOf(detail ? detail.profile : null, axisInfo);
const fixed = (value, digits) => Number(value).toLocaleString('en-US', { maximumFractionDigits: digits });

/** Position units per shaft revolution: 0x608F where it says more than
 * 1:1, else the product's; 0x6091 between motor and shaft. */
function perRevolution() {
  const u = axisInfo.units || {};
  const { encoder_resolution: encoder, gear_ratio: gear } = axisInfo.limits || {};
  let perMotorRev = u.position_per_revolution ?? null;
  if (encoder && encoder[1] && !(encoder[0] === 1 && encoder[1] === 1)) perMotorRev = encoder[0] / encoder[1];
  if (perMotorRev === null) return null;
  const ratio = gear && gear[1] ? gear[0] / gear[1] : 1; // motor revolutions per shaft revolution
  return { perMotorRev, perShaftRev: perMotorRev * ratio, geared: ratio !== 1 };
}

function renderConversions() {
  const u = axisInfo.units;
  if (!u) return;
  const rev = perRevolution();
  $('#conv-position').textContent = rev && status && status.position !== null && status.position !== undefined
    ? `= ${fixed(status.position / rev.perShaftRev, 3)} ${rev.geared ? 'shaft ' : ''}rev` : '';
  const rps = u.rps_per_velocity_unit;
  $('#conv-velocity').textContent = rps && status && status.velocity !== null && status.velocity !== undefined
    ? `= ${fixed(status.velocity * rps, 2)} rps (${fixed(status.velocity * rps * 60, 0)} rpm)` : '';
}

function renderUnits() {
  const u = axisInfo.units;
  if (!u) return;
  $('#unit-position').textContent = u.position;
  $('#unit-velocity').textContent = u.velocity;
  $('#unit-torque').textContent = '‰';
  const l = axisInfo.limits || {};
  const num = (v) => (v === null || v === undefined ? null : Number(v).toLocaleString('en-US'));
  const rps = (v) => (u.rps_per_velocity_unit ? ` (${fixed(v * u.rps_per_velocity_unit, 2)} rps)` : '');
  const rows = [
    ['Position', u.position + (u.position_per_revolution ? `, ${num(u.position_per_revolution)} per motor revolution` : '')],
    ['Velocity', u.velocity + (u.rps_per_velocity_unit ? `, 1 = ${fixed(u.rps_per_velocity_unit, 5)} rps` : '')],
    ['Acceleration', u.acceleration],
    u.vl_velocity ? ['VL velocity (0x6042, 0x6044)', `${u.vl_velocity}${l.vl_dimension_factor ? `, × ${l.vl_dimension_factor[0]}/${l.vl_dimension_factor[1]} (0x604C) = ${u.velocity}` : ''}`] : null,
    l.max_profile_velocity !== null && l.max_profile_velocity !== undefined ? ['Max profile velocity (0x607F)', `${num(l.max_profile_velocity)} ${u.velocity}${rps(l.max_profile_velocity)}`] : null,
    l.max_motor_speed !== null && l.max_motor_speed !== undefined ? ['Max motor speed (0x6080)', `${num(l.max_motor_speed)} ${u.velocity}${rps(l.max_motor_speed)}`] : null,
    l.profile_velocity !== null && l.profile_velocity !== undefined ? ['Profile velocity (0x6081)', `${num(l.profile_velocity)} ${u.velocity}${rps(l.profile_velocity)}`] : null,
    l.profile_acceleration !== null && l.profile_acceleration !== undefined ? ['Profile acceleration (0x6083)', `${num(l.profile_acceleration)} ${u.acceleration}`] : null,
    l.vl_max !== null && l.vl_max !== undefined ? ['VL min / max (0x6046)', `${num(l.vl_min ?? 0)} / ${num(l.vl_max)} ${u.vl_velocity || u.velocity}`] : null,
    ['Software limits (0x607D)', l.software_position_limit ? `${num(l.software_position_limit[0])} to ${num(l.software_position_limit[1])} ${u.position}` : 'none'],
    l.encoder_resolution ? ['Encoder resolution (0x608F)', `${num(l.encoder_resolution[0])} increments per ${num(l.encoder_resolution[1])} motor revolution(s)`] : null,
    l.gear_ratio ? ['Gear ratio (0x6091)', `${num(l.gear_ratio[0])} motor : ${num(l.gear_ratio[1])} shaft revolution(s)`] : null,
  ].filter(Boolean);
  $('#axis-limits').replaceChildren(...rows.flatMap(([term, text]) => [h('dt', {}, term), h('dd', {}, text)]));
  $('#units-note').textContent = u.vl_velocity && detail && detail.profile === 'umc'
    ? 'The UMC counts the profile velocity (0x6081) and the velocity readout (0x606C) both in increments/ms. '
      + 'A profile position move reaches 0x6081 only if it is long enough: at 0x6083 increments/ms² it peaks near '
      + '√(0x6083 × distance), and 0x6081 is capped to 0x607F and 0x6080.'
    : '';
}

// ---- state transitions, fault reset, halt ------------------------------------

let transitionsFor; // the state the buttons are for: redrawn only when it changes

function renderTransitions(available, force = false) {
  const state = status ? status.state : null;
  // A button replaced under a finger would lose its click.
  if (state === transitionsFor && !force) return;
  transitionsFor = state;
  if (!state) {
    transitionList.replaceChildren(h('p', { class: 'sub' }, 'Waiting for the drive’s state…'));
    return;
  }
  const buttons = available.map((t) => h('button', {
    type: 'button', class: `transition${t.target === 'operation_enabled' ? ' primary' : ''}${t.n === 11 ? ' warn' : ''}`,
    dataset: { target: t.target, transition: t.n },
    on: { click: (event) => transition(t, event.currentTarget) },
  }, h('span', { class: 'cmd' }, t.command), h('span', { class: 'to' }, `${t.n} → ${stateLabel(t.to)}`)));
  transitionList.replaceChildren(...(buttons.length ? buttons
    : [h('p', { class: 'sub' }, `No transition to command from ${stateLabel(status.state).toLowerCase()}: the drive leaves it by itself.`)]));
}

/** Runs one state-panel action: the others wait, the button shows it. The
 * result is said in the state panel and, for a button elsewhere (the fault
 * band's Fault reset), also beside it, where the tap was (`near`). */
async function stateAction(button, busyLabel, what, request, near = null) {
  acting = true;
  for (const other of document.querySelectorAll('#state-panel button, #fault-reset')) if (other !== button) other.disabled = true;
  const result = (el, state, ...content) => {
    say(el, state, ...content);
    if (near) say(near, state, ...content.map((c) => (c instanceof Node ? c.cloneNode(true) : c)));
  };
  result(stateResult, 'busy', `${what}…`);
  const outcome = await runAction(button, busyLabel, request);
  acting = false;
  if (outcome.ok) {
    applyStatus(outcome.value);
    result(stateResult, 'done', h('strong', {}, `${what}: done (${clock()}). `),
      `The drive is in ${stateLabel(outcome.value.state).toLowerCase()}.`);
  } else {
    result(stateResult, 'failed', h('strong', {}, `${what} failed (${clock()}): `), outcome.error.message);
    if (status) applyStatus({});
  }
  if (status) renderFault();
  if (status) renderTransitions(commandable(status.state), true);
  return outcome;
}

function transition(t, button) {
  if (t.target === 'fault-reset') return resetFault(button);
  return stateAction(button, 'Switching…', `${t.command} (${t.n})`,
    () => api(`${axisPath}/state`, { method: 'POST', body: { target: t.target }, headers: leaseHeaders() }));
}

async function resetFault(button) {
  const outcome = await stateAction(button, 'Resetting…', 'Fault reset',
    () => api(`${axisPath}/fault-reset`, { method: 'POST' }), button === faultReset ? faultResult : null);
  reloadNode();
  return outcome;
}

faultReset.addEventListener('click', () => resetFault(faultReset));
haltOn.addEventListener('click', async () => {
  const outcome = await stateAction(haltOn, 'Halting…', 'Halt',
    () => api(`${axisPath}/halt`, { method: 'POST', body: { halt: true } }));
  if (outcome.ok) dropLease(null);
});
// The stop bar kept in view (sticky under the top bar): Halt and Quick
// stop of this axis, whatever the rest of the page is doing.
async function quickAction(button, busyLabel, what, request) {
  quickResult.dataset.state = 'busy';
  quickResult.textContent = `${what}…`;
  const outcome = await runAction(button, busyLabel, request);
  if (outcome.ok) {
    applyStatus(outcome.value);
    dropLease(null);
    quickResult.dataset.state = 'done';
    quickResult.textContent = `${what}: done (${clock()}), ${stateLabel(outcome.value.state).toLowerCase()}.`;
  } else {
    quickResult.dataset.state = 'failed';
    quickResult.textContent = `${what} failed (${clock()}): ${outcome.error.message}`;
    if (status) applyStatus({});
  }
}
quickHalt.addEventListener('click', () => quickAction(quickHalt, 'Halting…', 'Halt',
  () => api(`${axisPath}/halt`, { method: 'POST', body: { halt: true } })));
quickStop.addEventListener('click', () => quickAction(quickStop, 'Stopping…', 'Quick stop',
  () => api(`${axisPath}/state`, { method: 'POST', body: { target: 'quick_stop_active' }, headers: leaseHeaders() })));

haltOff.addEventListener('click', async () => {
  const outcome = await stateAction(haltOff, 'Releasing…', 'Release halt',
    () => api(`${axisPath}/halt`, { method: 'POST', body: { halt: false }, headers: leaseHeaders() }));
  if (outcome.ok && outcome.value.lease) holdLease(outcome.value.lease);
});

// ---- motion lease ---------------------------------------------------------------
//
// A velocity, torque or duty-cycle move (and releasing halt in one of those
// modes) answers with a lease (docs/rest-api.md, "Motion leases"): the page renews it
// on the stream every third of its period, so it lapses, and the gateway
// halts the axis, as soon as this page goes away or loses the gateway.
// Further commands present it, so that the page may change its own motion.

const leaseStatus = $('#lease-status');
let lease = null; // {id, period_ms, mode}
let leaseTimer = null;

function holdLease(granted) {
  if (!granted) return;
  const renewing = lease && lease.id === granted.id;
  lease = granted;
  leaseStatus.dataset.held = 'yes';
  leaseStatus.textContent = `Motion lease held (${granted.mode}): renewed every ${Math.round(granted.period_ms / 3)} ms; `
    + `the gateway halts the axis ${granted.period_ms / 1000} s after this page goes away.`;
  if (renewing && leaseTimer) return;
  clearInterval(leaseTimer);
  leaseTimer = setInterval(renewLease, Math.max(100, granted.period_ms / 3));
  renewLease();
}

function dropLease(why) {
  if (!lease) return;
  lease = null;
  clearInterval(leaseTimer);
  leaseTimer = null;
  leaseStatus.dataset.held = why ? 'lapsed' : 'no';
  leaseStatus.textContent = why || 'No motion lease: the motion was stopped.';
}

async function renewLease() {
  if (!lease) return;
  if (stream.state === 'connected') {
    stream.send({ op: 'renew', leases: [lease.id] });
    return;
  }
  // No stream (yet): REST keeps the lease, though nothing then ends it
  // when the page goes away but its lapse.
  const id = lease.id;
  try {
    await api(`${axisPath}/lease`, { method: 'POST', body: { lease: id } });
  } catch (error) {
    if (lease && lease.id === id && error.code === 'unknown_lease') {
      dropLease(`The motion lease lapsed (${clock()}): the gateway halted the axis.`);
    }
  }
}

stream.onLease((message) => {
  if (message.op === 'error' && lease && message.lease === lease.id) {
    dropLease(`The motion lease lapsed (${clock()}): the gateway halted the axis. ${message.error?.message || ''}`);
  }
});

/** The headers that present the page's lease, if it holds one. */
function leaseHeaders() {
  return lease ? { 'candeck-lease': lease.id } : {};
}

// ---- motion -------------------------------------------------------------------

/**
 * The one place a move is requested (issue 8's motion lease goes here):
 * `request` is a `POST .../move` body; the answer is the axis as the
 * gateway read it once the motion started.
 */
async function move(request, button, clips = []) {
  const what = request.mode === 'velocity' && request.velocity === 0 ? 'Stop (velocity 0)' : MODE_LABELS[request.mode];
  result(moveResult, 'busy', `${what}: starting…`);
  const outcome = await runAction(button, 'Starting…', () => api(`${axisPath}/move`, { method: 'POST', body: request, headers: leaseHeaders() }));
  if (outcome.ok) {
    if (outcome.value.lease) holdLease(outcome.value.lease);
    else dropLease(null);
    applyStatus(outcome.value);
    const axis = outcome.value;
    result(moveResult, 'done', h('strong', {}, `${what}: started (${clock()}). `),
      `The drive reports ${modeName(axis).toLowerCase()}, position ${show(axis.position)} ${units().position}.`,
      ...clips.map((clip) => h('span', { class: 'clipped', dataset: { by: clip.by } }, ` ${clipText(clip, true)}`)));
  } else {
    result(moveResult, 'failed', h('strong', {}, `${what} failed (${clock()}): `), outcome.error.message);
    applyStatus({});
  }
}

function renderModes() {
  const units = unitsOf(detail.profile, axisInfo);
  if (!supported.length) {
    modeTabs.replaceChildren();
    motionHost.replaceChildren(h('p', { class: 'sub' }, 'This axis supports no motion mode the gateway can command.'));
    return;
  }
  if (!supported.includes(selectedMode)) {
    const current = status && MOVE_MODE_OF[status.mode];
    selectedMode = supported.includes(current) ? current : supported[0];
  }
  modeTabs.replaceChildren(...supported.map((mode) => h('button', {
    type: 'button', role: 'tab', class: 'tab', dataset: { mode },
    'aria-selected': mode === selectedMode ? 'true' : 'false',
    on: { click: () => { selectedMode = mode; renderModes(); } },
  }, MODE_LABELS[mode] || mode)));
  const built = motionForm(selectedMode, units, {
    onSubmit: move,
    onStop: move,
    onInvalid: (text) => result(moveResult, 'failed', h('strong', {}, 'Not sent: '), text),
    position: () => (status ? status.position : null),
  });
  moveButtons = built.buttons;
  motionHost.replaceChildren(built.form);
  if (status) applyStatus({});
}

// ---- stream -------------------------------------------------------------------

stream.subscribe(['emcy'], (data, message) => {
  if (fatal) return;
  if (message.lagged || (data.bus === bus && detail && data.node === detail.id)) reloadNode();
});

stream.subscribe(['nodes'], (data, message) => {
  if (fatal) return;
  if (message.lagged || (data.bus === bus && String(data.node) === String(detail ? detail.id : nodeText))) {
    if (!detail || !supported) load();
    else reloadNode();
  }
});

stream.onState(({ state, reconnected, error }) => {
  if (error) {
    problem('stream', `Live updates: ${error}`);
    return;
  }
  root.dataset.live = state === 'connected' ? 'yes' : 'no';
  if (state === 'connected') {
    problem('stream', null);
    askRate();
    if (reconnected && !fatal) load();
  }
});

stream.connect();
load();
