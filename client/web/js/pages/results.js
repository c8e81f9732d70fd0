// A finished job's result: the estimates' table (estimate, standard error,
// 95 % interval; truth and error when the dataset declares them), the correlation matrix, parameter traces per pass,
// measured against modelled outputs, and the residual diagnostics with their
// bands; a validation's measured against simulated outputs with fit %.
import {api} from '../api.js';
import {clear, fmt, fmtInterval, h, num, row} from '../dom.js';
import {color, plot} from '../plot.js';

export async function showResult(el, job, result, model, signal) {
  clear(el);
  if (result.identification) return identification(el, job, result.identification, model, signal);
  if (result.estimation) return estimation(el, job, result.estimation, model, signal);
  if (result.validation) return validation(el, result.validation, model);
  if (result.smoothing) return smoothing(el, result.smoothing, model);
}

// The true parameters the dataset declares (uploaded with them), by name.
async function declaredTruth(datasetId, signal) {
  if (!datasetId) return {};
  const info = await api('GET', `/datasets/${encodeURIComponent(datasetId)}`, undefined, {signal}).catch(() => null);
  return (info && info.trueParameters) || {};
}

// Truth and the error in standard errors, for the parameters the dataset
// declares (as the CLI's result table with --truth).
function truthColumns(names, truth, estimate, std) {
  if (!names.some((n) => n in truth)) return [];
  const value = (i) => (names[i] in truth ? num(truth[names[i]]) : NaN);
  const sigmas = (i) => (estimate[i] - value(i)) / std[i];
  return [['Truth', (i) => (names[i] in truth ? fmt(value(i), 5) : '–'), value],
    ['Error (σ)', (i) => (Number.isFinite(sigmas(i)) ? sigmas(i).toFixed(2) : '–'), sigmas]];
}

// "A1=10, k1 = 0.0791" (or "A1:10") -> {A1: 10, k1: 0.0791}; what does not read is left out.
function parseTruth(text) {
  const out = {};
  for (const part of String(text || '').split(',')) {
    const m = part.match(/^\s*([^=:\s]+)\s*[=:]\s*(\S+)\s*$/);
    if (m && Number.isFinite(Number(m[2]))) out[m[1]] = Number(m[2]);
  }
  return out;
}

// [min, max] over every series' finite values, padded by 5 %: an axis that
// shows every pass, not only the first's range.
function rangeOf(seriesValues) {
  let lo = Infinity, hi = -Infinity;
  for (const values of seriesValues) {
    for (const v of values) if (Number.isFinite(v)) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
  }
  if (!Number.isFinite(lo)) return [0, 1];
  const pad = hi > lo ? 0.05 * (hi - lo) : Math.max(Math.abs(lo) * 0.01, 1e-12);
  return [lo - pad, hi + pad];
}

// The parameters' estimates, a row each, with the unit the model declares.
function resultTable(names, cols, model) {
  const unitOf = (n) => ((model && model.paramUnits) || [])[((model && model.paramNames) || []).indexOf(n)] || '';
  return h('table', {id: 'result-table'},
    h('thead', {}, h('tr', {}, h('th', {}, 'Parameter'), h('th', {}, 'Unit'), cols.map(([title]) => h('th', {class: 'num'}, title)))),
    h('tbody', {}, names.map((n, i) => h('tr', {'data-param': n}, h('th', {}, n), h('td', {class: 'unit'}, unitOf(n)),
      cols.map(([title, f, value]) => h('td', {class: 'num', 'data-col': title, 'data-value': value ? String(value(i)) : null}, f(i)))))));
}

function correlationTable(names, corr) {
  return h('table', {class: 'corr', id: 'correlation'},
    h('thead', {}, h('tr', {}, h('th', {}), names.map((n) => h('th', {}, n)))),
    h('tbody', {}, names.map((n, i) => h('tr', {}, h('th', {}, n), names.map((_, j) => {
      const c = corr(i, j);
      const strong = i !== j && Math.abs(c) > 0.9;
      return h('td', {class: strong ? 'warn' : ''}, Number.isFinite(c) ? c.toFixed(3) : '–');
    })))));
}

// Sample autocorrelation at lags 1..lags.
function autocorrelation(e, lags) {
  const x = e.filter(Number.isFinite), n = x.length;
  const mean = x.reduce((a, b) => a + b, 0) / n;
  const d = x.map((v) => v - mean);
  const c0 = d.reduce((a, v) => a + v * v, 0) / n;
  const out = [];
  for (let k = 1; k <= lags; ++k) {
    let c = 0;
    for (let i = k; i < n; ++i) c += d[i] * d[i - k];
    out.push(c / n / c0);
  }
  return out;
}

function acfPlots(el, names, rowsOf, band, lags) {
  const box = h('div', {class: 'plots'});
  el.append(box);
  const k = Array.from({length: lags}, (_, i) => i + 1);
  names.forEach((n, i) => plot(box, {title: `autocorrelation of ${n}'s residuals`, x: k, xLabel: 'lag', width: 420, height: 200,
    series: [{label: n, values: rowsOf(i), points: true, width: 1},
      {label: '+95 %', values: k.map(() => band), color: '#6e7781', dash: [4, 4], width: 1},
      {label: '−95 %', values: k.map(() => -band), color: '#6e7781', dash: [4, 4], width: 1}]}));
}

async function identification(el, job, r, model, signal) {
  const names = r.paramNames || [];
  const mean = (r.thetaMean || []).map(num), std = (r.thetaStd || []).map(num), end = (r.theta || []).map(num);
  const filterStd = (r.filterThetaStd || []).map(num);
  // Results stored before the intervals have none (their std was √diag P).
  const intervals = (r.ciLower || []).length === names.length;
  const lower = (i) => (intervals ? num(r.ciLower[i]) : mean[i] - 1.96 * std[i]);
  const upper = (i) => (intervals ? num(r.ciUpper[i]) : mean[i] + 1.96 * std[i]);
  const spec = job.identification || {};
  const truth = await declaredTruth(spec.datasetId, signal);
  el.append(h('h2', {}, 'Estimates'),
    resultTable(names, [
      ['Estimate', (i) => fmt(mean[i], 5), (i) => mean[i]],
      ['Std error', (i) => fmt(std[i], 3), (i) => std[i]],
      ['95 % interval', (i) => fmtInterval(lower(i), upper(i))],
      ...(filterStd.length ? [['Filter std', (i) => fmt(filterStd[i], 3), (i) => filterStd[i]]] : []),
      ['End of last pass', (i) => fmt(end[i], 5)],
      ...truthColumns(names, truth, mean, std)], model),
    h('p', {class: 'muted', id: 'covariance-method'}, `Estimate: the mean over the last pass (the toolbox's). Std error and interval: ${r.covarianceMethod || '√diag P at its end'}.${filterStd.length ? ' Filter std: √diag P at the end (the toolbox\'s), which counts the record once per pass.' : ''}`),
    ...(r.warnings || []).map((w) => h('p', {class: 'warn'}, w)),
    h('p', {}, h('a', {class: 'button', id: 'validate-link', href: `#/validate?job=${encodeURIComponent(job.id)}&model=${encodeURIComponent(spec.model)}&dataset=${encodeURIComponent(spec.datasetId)}`}, 'Validate this estimate')));
  const nz = num(r.covariance && r.covariance.rows), nth = names.length, nx = nz - nth;
  if (num(r.thetaCovariance && r.thetaCovariance.rows) === nth && nth > 0) {
    const C = (i, j) => num(r.thetaCovariance.values[i + j * nth]);
    el.append(h('h2', {}, 'Correlation of the estimates'), correlationTable(names, (i, j) => C(i, j) / Math.sqrt(C(i, i) * C(j, j))));
  } else if (nz > 0) {
    const C = (i, j) => num(r.covariance.values[(nx + i) + (nx + j) * nz]);
    el.append(h('h2', {}, 'Correlation of the estimates'), correlationTable(names, (i, j) => C(i, j) / Math.sqrt(C(i, i) * C(j, j))));
  }
  // Parameter traces, a series per pass, the axis over every pass (and the
  // truth, drawn dashed where the dataset declares it or the user gives it).
  const t = (r.t || []).map(num);
  const traces = h('div', {class: 'plots', id: 'traces'});
  const passes = r.passes || [];
  const truthInput = h('input', {id: 'truth-input', size: 40, placeholder: 'A1=10, k1=0.0791',
    value: names.filter((n) => n in truth).map((n) => `${n}=${num(truth[n])}`).join(', ')});
  // The axes: the passes after the first (whose start from theta0 would
  // flatten the others into a line) and the truth; or every pass.
  const everyPass = h('input', {type: 'checkbox', id: 'traces-every-pass', checked: passes.length < 2});
  const drawTraces = () => {
    const given = parseTruth(truthInput.value);
    clear(traces);
    names.forEach((n, i) => {
      const series = passes.map((p, k) => ({label: `pass ${k + 1}`, values: row(p.thetaTrace, i), color: k === passes.length - 1 ? '#d1242f' : `hsl(215, 60%, ${80 - 45 * (k + 1) / passes.length}%)`, width: k === passes.length - 1 ? 2 : 1}));
      if (n in given) series.push({label: 'truth', values: t.map(() => given[n]), color: '#2da44e', dash: [6, 4], width: 1.5});
      const scaled = everyPass.checked ? series : series.slice(1);
      plot(traces, {title: n, x: t, width: 420, height: 220, yRange: rangeOf(scaled.map((s) => s.values)), series});
    });
  };
  truthInput.addEventListener('change', drawTraces);
  everyPass.addEventListener('change', drawTraces);
  el.append(h('h2', {}, 'Parameter traces per pass'),
    h('p', {class: 'row'}, h('label', {class: 'inline'}, 'Truth (drawn dashed): ', truthInput),
      passes.length < 2 ? null : h('label', {class: 'inline'}, everyPass, 'Axes over every pass (else passes 2 to ' + passes.length + ' and the truth)')),
    traces);
  drawTraces();
  // Outputs: measured against the model along the last pass.
  const data = await api('GET', `/datasets/${encodeURIComponent(spec.datasetId)}/data`, undefined, {signal}).catch(() => null);
  const outputs = (model.outputNames || []);
  const overlay = h('div', {class: 'plots', id: 'overlay'});
  el.append(h('h2', {}, 'Measured and modelled outputs (last pass)'), overlay);
  const first = num(spec.firstSample) || 0;
  outputs.forEach((y, i) => plot(overlay, {title: y, x: t, series: [
    {label: 'measured', values: data ? row(data.y, i).slice(first, first + t.length) : [], color: '#9aa4ae', width: 4},
    {label: 'model', values: row(r.yModel, i), color: '#d1242f'}]}));
  // Diagnostics: innovations' whiteness, NIS per pass.
  el.append(h('h2', {}, 'Diagnostics'));
  const n = t.length, lags = Math.min(40, Math.max(1, Math.floor(n / 4)));
  acfPlots(el, outputs, (i) => autocorrelation(row(r.innovations, i), lags), 1.96 / Math.sqrt(n), lags);
  const ny = outputs.length, nisBand = 1.96 * Math.sqrt(2 * ny / n);
  el.append(h('table', {id: 'nis'},
    h('thead', {}, h('tr', {}, h('th', {}, 'Pass'), h('th', {class: 'num'}, 'mean NIS'), h('th', {class: 'num'}, `95 % band (ny = ${ny})`),
      outputs.map((y) => h('th', {class: 'num'}, `innovation RMS ${y}`)))),
    h('tbody', {}, passes.map((p, k) => {
      const nis = num(p.nisMean), inside = Math.abs(nis - ny) <= nisBand;
      return h('tr', {}, h('td', {}, k + 1), h('td', {class: 'num ' + (inside ? 'ok' : 'warn')}, fmt(nis)),
        h('td', {class: 'num'}, `${fmt(ny - nisBand)} … ${fmt(ny + nisBand)}`),
        (p.innovationRms || []).map((v) => h('td', {class: 'num'}, fmt(v))));
    }))));
}

async function estimation(el, job, r, model, signal) {
  const names = r.paramNames || [];
  const theta = (r.theta || []).map(num), std = (r.thetaStd || []).map(num);
  const spec = job.identification || {};
  const truth = await declaredTruth(spec.datasetId, signal);
  el.append(h('h2', {}, 'Estimates'),
    resultTable(names, [
      ['Estimate', (i) => fmt(theta[i], 5), (i) => theta[i]],
      ['Std error', (i) => (r.fixed || [])[i] ? 'fixed' : fmt(std[i], 3), (i) => std[i]],
      ['95 % interval', (i) => fmtInterval((r.ciLower || [])[i], (r.ciUpper || [])[i])],
      ...truthColumns(names, truth, theta, std)], model),
    h('p', {class: 'muted'}, `${r.converged ? 'Converged' : 'Did not converge'} after ${num(r.iterations)} iterations (${r.termination || ''}); cost ${fmt(r.cost)}; gradient: ${r.gradient || ''}.`),
    r.covarianceMethod ? h('p', {class: 'muted', id: 'covariance-method'}, `Std error and interval: ${r.covarianceMethod}.`) : null,
    num(r.samples) > 0 ? h('p', {class: 'muted', id: 'criteria'}, `Log-likelihood ${fmt(r.logLikelihood, 10)}; AIC ${fmt(r.aic, 10)}, AICc ${fmt(r.aicc, 10)}, BIC ${fmt(r.bic, 10)} (k = ${num(r.estimatedQuantities)} estimated, n = ${num(r.samples)}; lower is better among models fitted to the same data).`) : null,
    ...(r.warnings || []).map((w) => h('p', {class: 'warn'}, w)),
    h('p', {}, h('a', {class: 'button', id: 'validate-link', href: `#/validate?job=${encodeURIComponent(job.id)}&model=${encodeURIComponent(spec.model)}&dataset=${encodeURIComponent(spec.datasetId)}`}, 'Validate this estimate')));
  if (r.correlation) el.append(h('h2', {}, 'Correlation of the estimates'), correlationTable(names, (i, j) => num(r.correlation.values[i + j * num(r.correlation.rows)])));
  const costs = (r.costHistory || []).map(num);
  const box = h('div', {class: 'plots', id: 'traces'});
  el.append(h('h2', {}, 'Cost per iteration'), box);
  plot(box, {title: 'cost', x: costs.map((_, i) => i + 1), xLabel: 'iteration', series: [{label: 'cost', values: costs, points: true}]});
  // ML's model output is its predictor's, one step ahead; OE's the simulation.
  const oneStep = r.method === 'IDENTIFICATION_METHOD_ML';
  (r.experiments || []).forEach((x, e) => {
    const t = (x.t || []).map(num), outputs = model.outputNames || [];
    const overlay = h('div', {class: 'plots', id: e === 0 ? 'overlay' : null});
    el.append(h('h2', {}, `Measured and modelled outputs, record ${e + 1}`), overlay);
    outputs.forEach((y, i) => {
      const fit = (x.fits || [])[i];
      plot(overlay, {title: `${y}${fit ? ` · fit ${fmt(fit.fitPercent, 3)} %` : ''}`, x: t, series: [
        {label: 'measured', values: row(x.yMeasured, i), color: '#9aa4ae', width: 4}, {label: oneStep ? 'one step ahead' : 'simulated', values: row(x.yModel, i), color: '#d1242f'}]});
    });
    const d = x.diagnostics;
    if (d && d.autocorrelation) {
      el.append(h('h3', {}, `Residual diagnostics, record ${e + 1}`), diagnosticsTables(d, outputs, model.inputNames || [], e === 0));
      acfPlots(el, outputs, (i) => row(d.autocorrelation, i), num(d.band), num(d.lags));
    }
  });
}

// The residual tests of one record, a table each, rows by the model's
// outputs and inputs: statistic, limit, p-value and degrees of freedom as
// riccatid computed them (nothing recomputed here), and the verdict.
function diagnosticsTables(d, outputs, inputs, first) {  // first: the ids, once a page
  const ny = (d.ljungBox || []).length, stats = d.crossStatistic || [];
  const nu = ny ? stats.length / ny : 0;
  const name = (names, i, prefix) => names[i] || `${prefix}${i + 1}`;
  const p = (v) => (Number.isFinite(num(v)) ? fmt(v, 3) : '–');
  const dof = (v) => (num(v) > 0 ? String(num(v)) : '–');  // absent in a result stored before riccatid sent it
  const verdict = (pass) => h('td', {class: pass ? 'ok verdict' : 'warn verdict'}, pass ? 'pass' : 'fail');
  const table = (id, caption, heads, rows) => h('table', {id: first ? id : null, class: 'diagnostics'}, h('caption', {}, caption),
    h('thead', {}, h('tr', {}, heads.map(([t, c]) => h('th', {class: c}, t)))), h('tbody', {}, rows));
  const numbers = ['Limit', 'p-value', 'dof'].map((t) => [t, 'num']);
  const limit = num(d.ljungBoxLimit);
  const tables = [table('diag-whiteness', `Whiteness: Ljung-Box Q over lags 1…${num(d.lags)}`,
    [['Output'], ['Q', 'num'], ...numbers, ['Verdict']],
    (d.ljungBox || []).map((q, i) => h('tr', {'data-output': name(outputs, i, 'y')}, h('th', {}, name(outputs, i, 'y')),
      h('td', {class: 'num'}, fmt(q)), h('td', {class: 'num'}, fmt(limit)), h('td', {class: 'num'}, p((d.ljungBoxP || [])[i])),
      h('td', {class: 'num'}, dof(d.ljungBoxDof)), verdict(num(q) <= limit))))];
  if (nu > 0) {
    tables.push(table('diag-inputs', `Independence from the inputs: N R² of the residual on the input at lags 0…${num(d.lags)}`,
      [['Output'], ['Input'], ['S', 'num'], ...numbers, ['Verdict']],
      stats.map((s, k) => {
        const lim = num((d.crossLimit || [])[k]), tested = lim > 0;  // a constant input: no limit, not tested
        return h('tr', {'data-output': name(outputs, Math.floor(k / nu), 'y'), 'data-input': name(inputs, k % nu, 'u')},
          h('th', {}, name(outputs, Math.floor(k / nu), 'y')), h('th', {}, name(inputs, k % nu, 'u')),
          h('td', {class: 'num'}, fmt(s)), h('td', {class: 'num'}, tested ? fmt(lim) : 'constant input'),
          h('td', {class: 'num'}, tested ? p((d.crossP || [])[k]) : '–'), h('td', {class: 'num'}, tested ? dof((d.crossDof || [])[k]) : '0'),
          verdict(!tested || num(s) <= lim));
      })));
  }
  if (Number.isFinite(num(d.nisMean))) {
    tables.push(table('diag-nis', 'Noise consistency: mean NIS in its band (two-sided)',
      [['Mean NIS', 'num'], ['Band', 'num'], ['p-value', 'num'], ['dof', 'num'], ['Verdict']],
      [h('tr', {}, h('td', {class: 'num'}, fmt(d.nisMean)), h('td', {class: 'num'}, `${fmt(d.nisLower)} … ${fmt(d.nisUpper)}`),
        h('td', {class: 'num'}, num(d.nisDof) > 0 ? p(d.nisP) : '–'), h('td', {class: 'num'}, dof(d.nisDof)), verdict(!!d.nisConsistent))]));
  }
  return h('div', {class: 'diagnostics-tables', id: first ? 'diagnostics' : null}, tables);
}

function validation(el, r, model) {
  const t = (r.t || []).map(num), outputs = model.outputNames || [];
  // A K-step-ahead prediction (validate's horizon) or the simulation.
  const horizon = num(r.horizon), modelled = horizon > 0 ? `predicted ${horizon} ahead` : 'simulated';
  el.append(h('h2', {}, horizon > 0 ? `Measured and predicted ${horizon} samples ahead` : 'Measured and simulated'),
    h('p', {class: 'muted'}, `Parameters: ${r.parametersFrom || ''}; initial states: ${r.x0From || ''}.${horizon > 0 ? ` Predictor: ${r.predictor || ''}.` : ''}`),
    h('table', {id: 'fits'},
      h('thead', {}, h('tr', {}, ['Output', 'Fit %', 'VAF %', 'RMSE'].map((c) => h('th', {class: 'num'}, c)))),
      h('tbody', {}, (r.fits || []).map((f) => h('tr', {'data-output': f.name}, h('th', {}, f.name),
        h('td', {class: 'num fit', 'data-value': String(num(f.fitPercent))}, fmt(f.fitPercent, 4)), h('td', {class: 'num'}, fmt(f.vafPercent, 4)), h('td', {class: 'num'}, fmt(f.rmse)))))));
  const overlay = h('div', {class: 'plots', id: 'overlay'});
  el.append(overlay);
  outputs.forEach((y, i) => {
    const fit = (r.fits || [])[i];
    plot(overlay, {title: `${y} · fit ${fit ? fmt(fit.fitPercent, 3) : '–'} %`, x: t, series: [
      {label: 'measured', values: row(r.yMeasured, i), color: '#9aa4ae', width: 4}, {label: modelled, values: row(r.ySimulated, i), color: color(0)}]});
  });
}

function smoothing(el, r, model) {
  const names = [...(model.stateNames || []), ...(model.paramNames || [])];
  const t = (r.t || []).map(num);
  const box = h('div', {class: 'plots', id: 'overlay'});
  el.append(h('h2', {}, 'Smoothed and filtered (±2σ)'), box);
  names.forEach((n, i) => {
    const z = row(r.zSmoothed, i), s = row(r.stdSmoothed, i);
    plot(box, {title: n, x: t, bands: [[2, 3]], series: [
      {label: 'smoothed', values: z, color: '#1f6feb'},
      {label: '+2σ', values: z.map((v, k) => v + 2 * s[k]), color: 'rgba(31,111,235,.4)', width: 1},
      {label: '−2σ', values: z.map((v, k) => v - 2 * s[k]), color: 'rgba(31,111,235,.4)', width: 1},
      {label: 'filtered', values: row(r.zFiltered, i), color: '#6e7781', width: 1}]});
  });
}
