// Identify: model and dataset first (their columns must match), then a
// field for every setting of an IdentificationSpec, made from riccatid's
// schema (settings_form.js) and shown where the chosen method and filter kind
// take it; experiments, excluded samples and output limits below. Submitting
// sends only what was filled and opens the job's page (#/jobs/<id>).
import {api} from '../api.js';
import {clear, errorBox, fmt, h, num} from '../dom.js';
import {FormError, loadSchema, settingsForm} from '../settings_form.js';

export function select(id, options, value) {
  return h('select', {id}, options.map(([v, label]) => h('option', {value: v, selected: v === value}, label)));
}

// "A1 [m^2]": a name with the unit the model declares, if any.
const label = (name, unit) => (unit ? `${name} [${unit}]` : name);
const list = (names) => (names && names.length ? names.join(', ') : 'none');

// Why a dataset cannot be identified with a model, or '' when it can: riccatid
// takes a dataset's inputs and outputs in order, so their counts must be the model's.
export function columnMismatch(m, d) {
  const problems = [];
  for (const [what, mine, theirs] of [['inputs', m.inputNames, d.inputNames], ['outputs', m.outputNames, d.outputNames]]) {
    if ((mine || []).length !== (theirs || []).length) {
      problems.push(`model ${m.name} has ${(mine || []).length} ${what} (${list(mine)}), dataset ${d.name} has ` +
        `${(theirs || []).length} (${list(theirs)})`);
    }
  }
  return problems.join('; ');
}

export async function show(main, r, signal) {
  const [models, datasets, schema] = await Promise.all([api('GET', '/models', undefined, {signal}),
    api('GET', '/datasets', undefined, {signal}), loadSchema(signal)]);
  const modelList = models.models || [];
  const datasetList = datasets.datasets || [];
  const modelName = r.query.get('model') || (modelList.find((m) => m.name === 'two_tank') || modelList[0] || {}).name;
  const modelSelect = select('model', modelList.map((m) => [m.name, m.name]), modelName);
  const datasetOptions = datasetList.map((d) => [d.id, `${d.name} (${num(d.samples)} samples)`]);
  const datasetSelect = select('dataset', datasetOptions, r.query.get('dataset') || (datasetList[0] || {}).id);
  const columns = h('p', {id: 'identify-columns'});
  const modelInfo = h('div', {id: 'model-info'});
  const form = settingsForm(schema, 'IdentificationSpec');
  const samples = samplesPart(datasetOptions);
  const status = h('div', {id: 'identify-status'});
  const submit = h('button', {class: 'primary', id: 'identify-submit', type: 'submit'}, 'Identify');
  const page = h('form', {id: 'identify', novalidate: true},
    h('div', {class: 'panel row'}, h('label', {}, 'Model', modelSelect), h('label', {}, 'Dataset', datasetSelect)),
    columns, modelInfo, form.element, samples.element, h('p', {}, submit), status);

  const chosenModel = () => modelList.find((x) => x.name === modelSelect.value);
  const datasetOf = (id) => datasetList.find((x) => x.id === id);
  // What stops a submit, or '': no model or dataset, or their columns (checked before anything is sent).
  const mismatch = () => {
    const m = chosenModel();
    if (!m) return 'Choose a model.';
    const ids = [datasetSelect.value, ...samples.experiments()];
    if (!ids[0]) return 'Choose a dataset.';
    const mismatched = ids.map((id) => columnMismatch(m, datasetOf(id) || {name: id})).filter(Boolean).join('; ');
    return mismatched ? `The columns do not match: ${mismatched}.` : '';
  };
  const draw = () => {
    const m = chosenModel();
    clear(modelInfo, m ? describe(m) : h('p', {class: 'muted'}, 'No models loaded.'));
    const problem = mismatch();
    clear(columns, problem ? h('span', {class: 'error'}, problem) : null);
    submit.disabled = !!problem;
    history.replaceState(null, '', `#/identify?model=${encodeURIComponent(modelSelect.value)}&dataset=${encodeURIComponent(datasetSelect.value || '')}`);
  };
  const update = () => {
    samples.show(form.method());
    draw();
  };
  modelSelect.addEventListener('change', draw);
  datasetSelect.addEventListener('change', draw);
  samples.element.addEventListener('change', draw);
  form.element.addEventListener('change', update);
  page.addEventListener('submit', async (e) => {
    e.preventDefault();
    clear(status);
    const problem = mismatch();
    if (problem) return clear(status, h('p', {class: 'error'}, problem));
    let spec;
    try {
      spec = {model: modelSelect.value, dataset_id: datasetSelect.value, ...form.value()};
      samples.fill(spec, form.method());
    } catch (err) {
      if (!(err instanceof FormError)) throw err;
      return clear(status, errorBox(err));
    }
    submit.disabled = true;
    try {
      const job = await api('POST', '/jobs/identification', spec);
      location.hash = '#/jobs/' + encodeURIComponent(job.id);
    } catch (err) {
      clear(status, errorBox(err));
      submit.disabled = false;
    }
  });
  clear(main, h('h1', {}, 'Identify'),
    datasetList.length ? null : h('p', {class: 'warn'}, 'No datasets yet: ', h('a', {href: '#/datasets'}, 'upload one'), ' first.'),
    page);
  update();
}

// The model's names, units, defaults and bounds: what the settings' values
// are written in (the order of [x; theta] for P0 and Q, of the outputs for R).
function describe(m) {
  const params = m.paramNames || [], units = m.paramUnits || [];
  const theta = m.thetaDefault || [], lower = m.thetaLower || [], upper = m.thetaUpper || [];
  const named = (names, unitsOf) => (names || []).map((n, i) => label(n, (unitsOf || [])[i])).join(', ') || 'none';
  return h('div', {class: 'panel'},
    h('p', {class: 'muted'}, `${m.name} ${m.version || ''}: ${m.description || ''}`),
    h('p', {}, h('b', {}, 'States '), named(m.stateNames, m.stateUnits), ' · ', h('b', {}, 'inputs '),
      named(m.inputNames, m.inputUnits), ' · ', h('b', {}, 'outputs '), named(m.outputNames, m.outputUnits),
      ' · ', h('b', {}, '[x; θ] '), [...(m.stateNames || []), ...params].join(', ')),
    h('table', {id: 'parameters'},
      h('thead', {}, h('tr', {}, ['Parameter', 'Default θ0', 'Lower bound', 'Upper bound'].map((c) => h('th', {}, c)))),
      h('tbody', {}, params.map((p, i) => h('tr', {'data-param': p},
        h('th', {}, label(p, units[i])),
        [theta[i], lower[i], upper[i]].map((v) => h('td', {class: 'num'}, fmt(v))))))));
}

// What the schema does not hold, since it is structure rather than a setting
// (as the CLI's --experiment, --exclude and --output-limit): more
// experiments (output error and likelihood), samples left out of an
// experiment, and outputs' limits in every experiment.
function samplesPart(datasetOptions) {
  const rows = h('div', {id: 'experiments'});
  const add = h('button', {type: 'button', id: 'experiment-add'}, 'Add an experiment');
  const experimentsPart = h('div', {id: 'experiments-part'},
    h('p', {class: 'muted'}, 'Output error and likelihood: more records of the system, the same parameters, each its own ' +
      'initial state (experiment 1 is the dataset above; 2, 3, ... these in order).'), rows, add);
  add.addEventListener('click', () => {
    const n = rows.children.length + 2;
    const remove = h('button', {type: 'button', class: 'danger'}, 'Remove');
    const row = h('div', {class: 'row experiment'},
      h('label', {}, `Experiment ${n}`, select(`experiment-${n}`, datasetOptions, (datasetOptions[0] || [])[0])), remove);
    remove.addEventListener('click', () => {
      row.remove();
      [...rows.children].forEach((r, i) => { r.querySelector('label').firstChild.textContent = `Experiment ${i + 2}`; });
      rows.dispatchEvent(new Event('change', {bubbles: true}));
    });
    rows.append(row);
    rows.dispatchEvent(new Event('change', {bubbles: true}));
  });
  const exclude = h('input', {id: 'exclude', size: 28, placeholder: '[E@]FIRST:END, ...', autocomplete: 'off'});
  const limits = h('input', {id: 'output-limit', size: 28, placeholder: 'OUTPUT=LO:HI, ...', autocomplete: 'off'});
  const element = h('fieldset', {'data-group': 'experiments'}, h('legend', {}, 'Experiments and samples'),
    experimentsPart,
    h('div', {class: 'settings'},
      h('div', {class: 'setting'}, h('label', {for: 'exclude'}, h('code', {}, '--exclude'),
        ' Leave samples FIRST to END-1 (0-based) of experiment E out (E: 1, the default, is the dataset above)'), exclude),
      h('div', {class: 'setting'}, h('label', {for: 'output-limit'}, h('code', {}, '--output-limit'),
        ' An output\'s saturation: samples where it is at or beyond a limit are left out, in every experiment; LO or HI may be empty'),
      limits)));
  const experiments = () => [...rows.querySelectorAll('select')].map((s) => s.value);
  const takesExperiments = (method) => method === 'oe' || method === 'ml';
  let currentMethod = '';

  const items = (text) => text.split(',').map((x) => x.trim()).filter((x) => x !== '');
  const count = (text, what) => {
    if (!/^\d+$/.test(text.trim())) throw new FormError(`${what} is not a whole number (0 or more)`);
    return Number(text.trim());
  };
  const bound = (text, what) => {
    if (text.trim() === '') return undefined;
    const v = Number(text.trim());
    if (!Number.isFinite(v)) throw new FormError(`${what}: "${text.trim()}" is not a number`);
    return v;
  };
  // Each experiment's mask: the limits of every output, and its excluded ranges.
  function masks(count_) {
    const out = Array.from({length: count_}, () => ({}));
    const lims = items(limits.value).map((item) => {
      const m = /^([^=]+)=([^:]*):(.*)$/.exec(item);
      if (!m) throw new FormError(`--output-limit: "${item}" is not OUTPUT=LO:HI`);
      const l = {output: m[1].trim()}, lo = bound(m[2], '--output-limit'), hi = bound(m[3], '--output-limit');
      if (lo !== undefined) l.lower = lo;
      if (hi !== undefined) l.upper = hi;
      return l;
    });
    if (lims.length) out.forEach((m) => { m.limits = lims; });
    for (const item of items(exclude.value)) {
      const m = /^(?:(\d+)@)?([^:]+):(.+)$/.exec(item);
      if (!m) throw new FormError(`--exclude: "${item}" is not [E@]FIRST:END (samples FIRST to END-1, 0-based, of experiment E)`);
      const e = m[1] === undefined ? 1 : count(m[1], `--exclude: "${item}": E`);
      if (e < 1 || e > count_) {
        throw new FormError(`--exclude ${item}: there is no experiment ${e} (1 is the dataset` +
          (count_ > 1 ? `, 2 to ${count_} the experiments added` : '') + ')');
      }
      (out[e - 1].excluded = out[e - 1].excluded || []).push(
        {first: count(m[2], `--exclude: "${item}": FIRST`), end: count(m[3], `--exclude: "${item}": END`)});
    }
    return out;
  }
  return {
    element,
    experiments: () => (takesExperiments(currentMethod) ? experiments() : []),
    show(method) {
      currentMethod = method;
      experimentsPart.hidden = !takesExperiments(method);
    },
    // Experiment 1's mask into the spec, and the experiments with theirs,
    // each starting as experiment 1 does (its initial_state), as the CLI sends them.
    fill(spec, method) {
      const more = takesExperiments(method) ? experiments() : [];
      const m = masks(1 + more.length);
      if (Object.keys(m[0]).length) spec.mask = m[0];
      if (more.length) {
        spec.experiments = more.map((id, i) => {
          const e = {dataset_id: id};
          if (spec.initial_state) e.initial_state = spec.initial_state;
          if (Object.keys(m[i + 1]).length) e.mask = m[i + 1];
          return e;
        });
      }
    },
  };
}
