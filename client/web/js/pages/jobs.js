// Jobs: the list (state, times, model, dataset; cancel; open; a box to pick
// output-error and likelihood fits to compare), a job's page (#/jobs/<id>):
// live progress and parameter estimates by server-sent events, then its
// result (results.js), and the comparison of fits (#/jobs?compare=a,b):
// riccatid's CompareJobs answer.
import {api, events} from '../api.js';
import {clear, enumName, enumOrDefault, errorBox, fmt, h, num, when} from '../dom.js';
import {plot, setData} from '../plot.js';
import {showResult} from './results.js';

const kindOf = (job) => (job.identification ? 'identification' : job.validation ? 'validation' : job.smoothing ? 'smoothing' : '');
const specOf = (job) => job.identification || job.validation || job.smoothing || {};
const stateOf = (job) => enumName(job.state, 'JOB_STATE_');
const terminal = (s) => ['SUCCEEDED', 'FAILED', 'CANCELLED'].includes(s);

// Output error and likelihood: the optimiser's iteration limit (0: riccatid's 200).
function maxIterationsOf(job) {
  const spec = job.identification || {};
  if (!['IDENTIFICATION_METHOD_OE', 'IDENTIFICATION_METHOD_ML'].includes(spec.method)) return 0;
  return num((spec.estimation || {}).maxIterations) || 200;
}

// How far a job is, 0 to 1: the passes' samples; for output error and
// likelihood the iterations of max_iterations (an upper bound: it usually
// converges first), the passes that give its start counting as the first.
function fractionDone(job) {
  const p = job.progress || {};
  const passes = num(p.passes) || 0, samples = num(p.samples) || 0;
  const inPasses = passes && samples ? Math.min(1, ((num(p.passNumber) || 1) - 1 + (num(p.sample) || 0) / samples) / passes) : 0;
  const maxIterations = maxIterationsOf(job);
  if (!maxIterations) return inPasses;
  return num(p.iteration) ? Math.min(1, num(p.iteration) / maxIterations) : inPasses / maxIterations;
}

// "pass 3/10", "iteration 12/200": the list's column.
function progressText(job) {
  const p = job.progress || {}, maxIterations = maxIterationsOf(job);
  if (maxIterations && num(p.iteration)) return `iteration ${num(p.iteration)}/${maxIterations}`;
  return num(p.passes) ? `pass ${num(p.passNumber)}/${num(p.passes)}` : '';
}

// Identifications by output error or likelihood: what compare takes.
const comparable = (job) => stateOf(job) === 'SUCCEEDED' &&
  ['IDENTIFICATION_METHOD_OE', 'IDENTIFICATION_METHOD_ML'].includes((job.identification || {}).method);

export async function show(main, r, signal) {
  if (r.id) return showJob(main, r.id, signal);
  if (r.query.get('compare')) {
    const validations = r.query.get('validations') ? r.query.get('validations').split(',') : [];
    return showComparison(main, r.query.get('compare').split(','), validations, signal);
  }
  const picked = new Set();  // kept across the list's redraws
  const compareButton = h('button', {id: 'compare-jobs', disabled: true,
    onclick: () => { location.hash = '#/jobs?compare=' + [...picked].map(encodeURIComponent).join(','); }}, 'Compare fits');
  const pick = (job) => (comparable(job) ? h('input', {type: 'checkbox', class: 'pick', checked: picked.has(job.id),
    title: 'compare this fit', onchange: (e) => {
      if (e.target.checked) picked.add(job.id); else picked.delete(job.id);
      compareButton.disabled = picked.size < 2;
    }}) : null);
  const draw = async () => {
    const [list, datasets] = await Promise.all([api('GET', '/jobs', undefined, {signal}), api('GET', '/datasets', undefined, {signal})]);
    const names = Object.fromEntries((datasets.datasets || []).map((d) => [d.id, d.name]));
    const jobs = (list.jobs || []).slice().sort((a, b) => String(b.created).localeCompare(String(a.created)));
    clear(main, h('h1', {}, 'Jobs'), jobs.length === 0 ? h('p', {class: 'muted'}, 'No jobs yet: ', h('a', {href: '#/identify'}, 'identify'), ' a model.') :
      h('table', {class: 'wide', id: 'jobs'},
        h('thead', {}, h('tr', {}, ['', 'Job', 'Kind', 'State', 'Model', 'Dataset', 'Progress', 'Created', 'Started', 'Finished', ''].map((c) => h('th', {}, c)))),
        h('tbody', {}, jobs.map((job) => {
          const spec = specOf(job), state = stateOf(job), p = job.progress || {};
          return h('tr', {'data-id': job.id},
            h('td', {}, pick(job)),
            h('td', {}, h('a', {href: '#/jobs/' + encodeURIComponent(job.id)}, job.id)),
            h('td', {}, kindOf(job)),
            h('td', {class: 'state ' + state}, state),
            h('td', {}, spec.model || ''),
            h('td', {}, names[spec.datasetId] || spec.datasetId || ''),
            h('td', {}, progressText(job)),
            h('td', {}, when(job.created)), h('td', {}, when(job.started)), h('td', {}, when(job.finished)),
            h('td', {}, terminal(state) ? null : h('button', {class: 'danger', onclick: async () => {
              await api('POST', `/jobs/${encodeURIComponent(job.id)}/cancel`);
              draw();
            }}, 'Cancel')));
        }))));
  };
  await draw();
  main.append(h('p', {}, compareButton, h('span', {class: 'muted'}, ' the output-error and likelihood fits ticked: likelihood, AIC, BIC, fit, and a likelihood-ratio test of each nested pair')));
  // While the page is open, the list follows the jobs (the button stays below it).
  const redraw = async () => { await draw(); main.append(compareButton.parentElement); };
  const timer = setInterval(() => redraw().catch(() => {}), 3000);
  signal.addEventListener('abort', () => clearInterval(timer));
}

async function showJob(main, id, signal) {
  const job = await api('GET', '/jobs/' + encodeURIComponent(id), undefined, {signal});
  const spec = specOf(job);
  const model = spec.model ? await api('GET', '/models/' + encodeURIComponent(spec.model), undefined, {signal}) : {};
  const params = model.paramNames || [];
  const stateEl = h('span', {class: 'state', id: 'job-state'});
  const bar = h('div');
  const progressText = h('span', {class: 'muted', id: 'job-progress'});
  const cancel = h('button', {class: 'danger', id: 'job-cancel', onclick: async () => {
    try { await api('POST', `/jobs/${encodeURIComponent(id)}/cancel`); } catch (err) { main.append(errorBox(err)); }
  }}, 'Cancel');
  // The method and, where it runs one, the filter kind: riccatid's defaults
  // where the request left them out.
  const method = enumOrDefault(spec.method, 'IDENTIFICATION_METHOD_', 'FILTER');
  const runsFilter = !job.identification || method !== 'OE' || num(spec.initPasses) > 0;
  const live = h('div', {class: 'plots', id: 'live'});
  const result = h('div', {id: 'result'});
  clear(main, h('h1', {}, `${kindOf(job)} job `, h('span', {id: 'job-id'}, id)),
    h('p', {}, `${spec.model || ''} on dataset `, h('a', {href: '#/datasets/' + encodeURIComponent(spec.datasetId || '')}, spec.datasetId || ''),
      job.identification ? ` · ${method}` : '',
      spec.filter && runsFilter ? ` · ${enumOrDefault(spec.filter.kind, 'FILTER_KIND_', 'EKF')}` : ''),
    h('div', {class: 'panel row'}, 'State: ', stateEl, h('div', {class: 'progress'}, bar), progressText, cancel),
    live, result);

  // Live parameter estimates: one point per event (decimated by riccatid),
  // beside the truth where the dataset declares it.
  const dataset = job.identification && spec.datasetId
    ? await api('GET', '/datasets/' + encodeURIComponent(spec.datasetId), undefined, {signal}).catch(() => null) : null;
  const truth = (dataset && dataset.trueParameters) || {};
  const xs = [], ys = params.map(() => []);
  const withTruth = (i) => (params[i] in truth ? [ys[i], xs.map(() => num(truth[params[i]]))] : [ys[i]]);
  let tracePlot = null;
  const update = (j) => {
    const state = stateOf(j), p = j.progress || {};
    stateEl.className = 'state ' + state;
    clear(stateEl, state);
    cancel.style.display = terminal(state) ? 'none' : '';
    const done = state === 'SUCCEEDED' ? 1 : fractionDone(j);
    bar.style.width = `${Math.min(100, 100 * done).toFixed(1)}%`;
    const maxIterations = maxIterationsOf(j);
    clear(progressText, num(p.passes) ? `pass ${num(p.passNumber)} of ${num(p.passes)}, sample ${num(p.sample)} of ${num(p.samples)}` : '',
      num(p.iteration) ? ` · iteration ${num(p.iteration)} of at most ${maxIterations}, cost ${fmt(p.cost)}` : '');
    if (j.error && j.error.message) clear(result, errorBox(j.error.message));
    const theta = (p.theta || []).map(num);
    if (theta.length === params.length && params.length > 0 && !terminal(state)) {
      xs.push(xs.length ? xs[xs.length - 1] + 1 : 0);
      theta.forEach((v, i) => ys[i].push(v));
      if (!tracePlot) {
        tracePlot = h('div', {class: 'plots', id: 'live-traces'});
        live.append(h('h2', {}, 'Estimates as it runs'), tracePlot);
        params.forEach((n, i) => plot(tracePlot, {title: n, x: xs, xLabel: 'update', width: 300, height: 180, series: [
          {label: n, values: ys[i], points: true},
          ...(n in truth ? [{label: 'truth', values: withTruth(i)[1], color: '#2da44e', dash: [6, 4], width: 1.5}] : [])]}));
      } else {
        [...tracePlot.children].forEach((box, i) => setData(box, xs, withTruth(i)));
      }
    }
  };
  update(job);
  let last = job;
  if (!terminal(stateOf(job))) {
    await events(`/jobs/${encodeURIComponent(id)}/events`, (name, data) => {
      if (name === 'job') { last = data; update(data); }
    }, signal);
  }
  if (stateOf(last) === 'SUCCEEDED') {
    clear(live);  // the result's traces replace the live ones
    const res = await api('GET', `/jobs/${encodeURIComponent(id)}/result`, undefined, {signal});
    await showResult(result, last, res, model, signal);
  }
}

// Each compared job validated on one record (POST /jobs/validation, as
// `riccati compare --data`), waited for; their ids in the jobs' order.
async function validateEach(jobs, datasetId, horizon, signal) {
  const ids = [];
  for (const j of jobs) {
    const spec = {model: j.model, datasetId, identificationJobId: j.jobId, initialState: {firstMeasurement: true}};
    if (horizon) spec.horizon = horizon;
    const job = await api('POST', '/jobs/validation', spec, {signal});
    for (;;) {
      const now = await api('GET', `/jobs/${encodeURIComponent(job.id)}`, undefined, {signal});
      if (now.state === 'JOB_STATE_SUCCEEDED') break;
      if (['JOB_STATE_FAILED', 'JOB_STATE_CANCELLED'].includes(now.state)) {
        throw new Error(`the validation of job ${j.jobId}: ${(now.error && now.error.message) || now.state}`);
      }
      await new Promise((done) => setTimeout(done, 300));
    }
    ids.push(job.id);
  }
  return ids;
}

// riccatid's comparison of the fits (CompareJobs): the criteria, the lowest
// marked, each output's fit, and the likelihood-ratio tests; with
// validations of the jobs on one record, their fits there too, and a form to
// make them.
async function showComparison(main, ids, validations, signal) {
  clear(main, h('h1', {}, 'Fits compared'));
  let r, datasets;
  try {
    [r, datasets] = await Promise.all([
      api('POST', '/jobs/compare', {jobIds: ids, validationJobIds: validations}, {signal}),
      api('GET', '/datasets', undefined, {signal})]);
  } catch (err) {
    return main.append(errorBox(err), h('p', {}, h('a', {href: '#/jobs'}, 'Jobs')));
  }
  const outputs = r.outputs || [];
  const validated = Boolean(r.validationDatasetId);
  const record = (datasets.datasets || []).find((d) => d.id === r.validationDatasetId);
  const on = validated ? `${r.validationHorizon ? `${num(r.validationHorizon)}-step` : 'simulated'} on ${record ? record.name : r.validationDatasetId}` : '';
  const mark = (v, lowest) => `${fmt(v, 10)}${lowest ? ' *' : ''}`;
  main.append(h('table', {class: 'wide', id: 'comparison'},
    h('thead', {}, h('tr', {}, ['Job', 'Model', 'Method', 'k', 'n', 'Log-likelihood', 'AIC', 'AICc', 'BIC', ...outputs.map((o) => `Fit % ${o}`),
      ...(validated ? outputs.map((o) => `Fit % ${o}, ${on}`) : [])]
      .map((c, i) => h('th', {class: i >= 3 ? 'num' : ''}, c)))),
    h('tbody', {}, (r.jobs || []).map((j) => h('tr', {'data-id': j.jobId},
      h('td', {}, h('a', {href: '#/jobs/' + encodeURIComponent(j.jobId)}, j.jobId)), h('td', {}, j.model),
      h('td', {}, enumName(j.method, 'IDENTIFICATION_METHOD_').toLowerCase()),
      h('td', {class: 'num'}, String(num(j.estimatedQuantities))), h('td', {class: 'num'}, String(num(j.samples))),
      h('td', {class: 'num'}, fmt(j.logLikelihood, 10)),
      h('td', {class: 'num aic' + (j.lowestAic ? ' best' : '')}, mark(j.aic, j.lowestAic)),
      h('td', {class: 'num'}, fmt(j.aicc, 10)),
      h('td', {class: 'num bic' + (j.lowestBic ? ' best' : '')}, mark(j.bic, j.lowestBic)),
      ...(j.fits || []).map((f) => h('td', {class: 'num'}, fmt(f.fitPercent, 4))),
      ...(j.validationFits || []).map((f) => h('td', {class: 'num validation', 'data-output': f.name}, fmt(f.fitPercent, 4))))))),
  h('p', {class: 'muted'}, '* the lowest: the best of these fits by that criterion (lower is better among fits to the same data); fit %: the first record\'s, output error\'s simulated, likelihood\'s one step ahead' +
    (validated ? `; on the common record: each model at its estimate, ${on}.` : '.')));
  // Every fit on one record of the user's choice, simulated or K steps ahead.
  const datasetSelect = h('select', {id: 'compare-dataset'}, (datasets.datasets || []).map((d) =>
    h('option', {value: d.id, selected: d.id === r.validationDatasetId}, d.name)));
  const horizon = h('input', {type: 'number', min: '1', step: '1', id: 'compare-horizon', placeholder: 'simulation',
    value: r.validationHorizon ? String(r.validationHorizon) : ''});
  const status = h('div', {id: 'compare-status'});
  const go = h('button', {class: 'primary', id: 'compare-validate', type: 'submit'}, 'Validate each and compare');
  const form = h('form', {class: 'panel', id: 'compare-record'},
    h('div', {class: 'row'}, h('label', {}, 'Common validation record', datasetSelect),
      h('label', {}, 'Horizon (samples ahead; empty: simulation)', horizon)), h('p', {}, go), status);
  form.addEventListener('submit', async (e) => {
    e.preventDefault();
    const k = horizon.value === '' ? 0 : Number(horizon.value);
    if (horizon.value !== '' && !(Number.isInteger(k) && k >= 1)) {
      return clear(status, errorBox(new Error('horizon: a whole number of samples, at least 1 (empty: the simulation)')));
    }
    go.disabled = true;
    clear(status, h('p', {class: 'muted'}, 'validating each fit on the record ...'));
    try {
      const made = await validateEach(r.jobs || [], datasetSelect.value, k, signal);
      location.hash = '#/jobs?compare=' + ids.map(encodeURIComponent).join(',') + '&validations=' + made.map(encodeURIComponent).join(',');
    } catch (err) {
      clear(status, errorBox(err));
      go.disabled = false;
    }
  });
  main.append(form);
  const tests = r.tests || [];
  if (tests.length) {
    main.append(h('h2', {}, 'Likelihood-ratio tests'), h('ul', {id: 'ratio-tests'}, tests.map((t) => h('li', {'data-smaller': t.smaller, 'data-larger': t.larger},
      `${t.smaller} within ${t.larger}: 2 (ln L_large − ln L_small) = ${fmt(t.statistic, 6)} on ${num(t.dof)} dof, p = ${fmt(t.p, 3)}: `,
      h('strong', {}, t.significant ? 'the larger model fits significantly better (5 %)' : 'no significant gain: the smaller model suffices (5 %)')))));
  }
}
