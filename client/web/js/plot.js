// Time series with uPlot (vendor/uplot, pinned in package-lock.json): fast on
// 100k points, drawn on a canvas.
import uPlot from '../vendor/uplot/uPlot.esm.js';
import {h, tickLabels} from './dom.js';

const kPalette = ['#1f6feb', '#d1242f', '#2da44e', '#bf8700', '#8250df', '#0598bc', '#e16f24', '#6e7781'];
export function color(i) { return kPalette[i % kPalette.length]; }

// The ticks' labels, from their spacing (tickLabels: distinct).
const ticks = (u, splits, axis, space, increment) => tickLabels(splits, increment);

// The least room between two y ticks: uPlot's 30 px, but never so much that a
// short plot (a live session's) gets fewer than three ticks, which could
// leave one label on its axis and no scale to read.
const ySpace = (u, axis, min, max, plotHeight) => Math.min(30, plotHeight / 4);

const clean = (values) => Array.from(values, (v) => (Number.isFinite(v) ? v : null));

// plot(parent, {title, x, xLabel, yLabel, series: [{label, values, color, dash}], bands: [[upper, lower]],
//   yRange: [min, max]})
// appends a plot to parent and returns it (its uPlot in .uplot, for setData).
// bands: pairs of series numbers (1 = the first series) whose area is shaded.
// yRange: the y axis's range, fixed (else from the data, redone at setData).
export function plot(parent, opts) {
  const box = h('div', {class: 'plot', 'data-title': opts.title || ''});
  parent.append(box);
  const series = [{label: opts.xLabel || 't (s)'}];
  opts.series.forEach((s, i) => series.push({
    label: s.label,
    stroke: s.color || color(i),
    width: s.width || 1.5,
    dash: s.dash,
    points: {show: !!s.points, size: 5},
    spanGaps: true,
  }));
  const u = new uPlot({
    title: opts.title,
    width: opts.width || 620,
    height: opts.height || 240,
    series,
    bands: (opts.bands || []).map(([a, b]) => ({series: [a, b], fill: 'rgba(31,111,235,0.13)'})),
    scales: opts.yRange ? {x: {time: false}, y: {auto: false, range: () => opts.yRange}} : {x: {time: false}},
    axes: [{label: opts.xLabel || 't (s)', values: ticks}, {label: opts.yLabel || '', values: ticks, size: 60, space: ySpace}],
    legend: {live: true},
  }, [clean(opts.x), ...opts.series.map((s) => clean(s.values))], box);
  box.uplot = u;
  return box;
}

export function setData(box, x, seriesValues) {
  box.uplot.setData([clean(x), ...seriesValues.map(clean)]);
}
