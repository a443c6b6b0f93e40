// The tuning page's step-response chart (issue 32: "the chart scales to the
// response"). The vertical axis spans what is drawn, the target and the
// actual values with a margin: an overshoot stays inside the plot and a
// small step fills it as a large one does. The horizontal axis is the
// run's duration. The runs drawn together are the latest and the earlier
// runs of the same step (same loop, from and to), so the gains they ran
// with can be compared; a run of another step would squash the latest's
// scale, and is only listed.

/** Earlier runs drawn with the latest, at most. */
export const OVERLAID = 3;
/** The latest run's colour; the earlier ones' in order, oldest last. */
export const LATEST_COLOUR = '#1d3557';
export const EARLIER_COLOURS = ['#e07a1f', '#2a9d8f', '#8e6cc9'];
const TARGET_COLOUR = '#c8102e';
// Room for the tick labels and the axes' units.
const PAD = { left: 70, right: 16, top: 26, bottom: 42 };
// The part of the range added above and below the samples' span.
const MARGIN = 0.05;

/** The runs of `runs` (oldest first) drawn with the last one, oldest first. */
export function comparable(runs) {
  const latest = runs[runs.length - 1];
  if (!latest) return [];
  return runs
    .filter((r) => r.samples && r.samples.length && r.loop === latest.loop && r.from === latest.from && r.to === latest.to)
    .slice(-(OVERLAID + 1));
}

/** The colour of `run` on the chart, or null when it is not drawn. */
export function colourOf(run, drawn) {
  const at = drawn.indexOf(run);
  if (at < 0) return null;
  return at === drawn.length - 1 ? LATEST_COLOUR : EARLIER_COLOURS[drawn.length - 2 - at];
}

/**
 * The axes' ranges for `drawn` (runs with `from`, `to` and samples
 * `[t_ms, target, actual]`): time from the first sample to the last,
 * values from the lowest to the highest of the levels and the actual
 * values, widened by the margin on each side.
 */
export function scaleOf(drawn) {
  let tMin = Infinity;
  let tMax = -Infinity;
  let low = Infinity;
  let high = -Infinity;
  for (const run of drawn) {
    low = Math.min(low, run.from, run.to);
    high = Math.max(high, run.from, run.to);
    for (const [t, target, actual] of run.samples) {
      tMin = Math.min(tMin, t);
      tMax = Math.max(tMax, t);
      low = Math.min(low, target, actual);
      high = Math.max(high, target, actual);
    }
  }
  if (!(tMax > tMin)) tMax = tMin + 1;
  if (high === low) { high += 1; low -= 1; }
  const margin = (high - low) * MARGIN;
  return { tMin, tMax, yMin: low - margin, yMax: high + margin };
}

/** About `count` round values between `lo` and `hi` (1, 2 or 5 × 10ⁿ apart). */
export function ticks(lo, hi, count = 5) {
  const rough = (hi - lo) / count;
  if (!(rough > 0)) return [];
  const magnitude = 10 ** Math.floor(Math.log10(rough));
  const norm = rough / magnitude;
  const step = (norm < 1.5 ? 1 : norm < 3 ? 2 : norm < 7 ? 5 : 10) * magnitude;
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) out.push(+v.toPrecision(12));
  return out;
}

const label = (v) => (Math.abs(v) >= 1000 ? String(Math.round(v)) : String(+v.toPrecision(4)));

/**
 * Draws `drawn` (from `comparable`) on `canvas`, values in `unit`. The
 * canvas carries what it drew: `data-y-min`, `data-y-max`, `data-t-min`,
 * `data-t-max` (the axes' ranges), `data-plot` (the plot's left, top,
 * right and bottom in canvas pixels), `data-runs` and `data-unit`.
 */
export function drawStep(canvas, drawn, unit) {
  const ctx = canvas.getContext('2d');
  const { width, height } = canvas;
  ctx.clearRect(0, 0, width, height);
  canvas.dataset.runs = String(drawn.length);
  if (!drawn.length) {
    for (const key of ['yMin', 'yMax', 'tMin', 'tMax', 'plot', 'unit']) delete canvas.dataset[key];
    return;
  }
  const { tMin, tMax, yMin, yMax } = scaleOf(drawn);
  const plot = { left: PAD.left, top: PAD.top, right: width - PAD.right, bottom: height - PAD.bottom };
  const x = (t) => plot.left + ((t - tMin) / (tMax - tMin)) * (plot.right - plot.left);
  const y = (v) => plot.bottom - ((v - yMin) / (yMax - yMin)) * (plot.bottom - plot.top);
  Object.assign(canvas.dataset, {
    yMin: String(yMin),
    yMax: String(yMax),
    tMin: String(tMin),
    tMax: String(tMax),
    plot: [plot.left, plot.top, plot.right, plot.bottom].join(','),
    unit,
  });

  // Grid, ticks and the axes' units.
  ctx.font = '12px system-ui, sans-serif';
  ctx.lineWidth = 1;
  ctx.fillStyle = '#5f6b7a';
  ctx.strokeStyle = '#e6eaf0';
  ctx.textAlign = 'right';
  ctx.textBaseline = 'middle';
  for (const v of ticks(yMin, yMax)) {
    const at = Math.round(y(v)) + 0.5;
    ctx.beginPath();
    ctx.moveTo(plot.left, at);
    ctx.lineTo(plot.right, at);
    ctx.stroke();
    ctx.fillText(label(v), plot.left - 6, at);
  }
  ctx.textAlign = 'center';
  ctx.textBaseline = 'top';
  for (const t of ticks(tMin, tMax, 8)) {
    const at = Math.round(x(t)) + 0.5;
    ctx.beginPath();
    ctx.moveTo(at, plot.top);
    ctx.lineTo(at, plot.bottom);
    ctx.stroke();
    ctx.fillText(label(t), at, plot.bottom + 4);
  }
  ctx.textAlign = 'left';
  ctx.fillText(unit, 4, 4);
  ctx.textAlign = 'right';
  ctx.fillText('ms after the step', plot.right, plot.bottom + 22);
  ctx.strokeStyle = '#b8c2d0';
  ctx.strokeRect(plot.left + 0.5, plot.top + 0.5, plot.right - plot.left - 1, plot.bottom - plot.top - 1);

  // The target, then the actual of each run, the latest on top. Nothing
  // is drawn outside the plot (the scale keeps everything inside anyway).
  ctx.save();
  ctx.beginPath();
  ctx.rect(plot.left, plot.top, plot.right - plot.left, plot.bottom - plot.top);
  ctx.clip();
  const latest = drawn[drawn.length - 1];
  ctx.strokeStyle = TARGET_COLOUR;
  ctx.lineWidth = 1;
  ctx.setLineDash([5, 4]);
  ctx.beginPath();
  latest.samples.forEach(([t, target], j) => (j ? ctx.lineTo(x(t), y(target)) : ctx.moveTo(x(t), y(target))));
  ctx.stroke();
  ctx.setLineDash([]);
  drawn.forEach((run) => {
    ctx.lineWidth = run === latest ? 2.5 : 1.5;
    ctx.strokeStyle = colourOf(run, drawn);
    ctx.beginPath();
    run.samples.forEach(([t, , actual], j) => (j ? ctx.lineTo(x(t), y(actual)) : ctx.moveTo(x(t), y(actual))));
    ctx.stroke();
  });
  ctx.restore();
}
