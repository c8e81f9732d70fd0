// A request's settings as a form, made from riccatid's schema (GET
// /api/v1/schema: the proto's riccati.v1.setting options, the same ones the
// CLI's flags and the Python client's keywords are made from). A field per
// setting, grouped, shown only where the chosen method and filter kind take
// it. Nothing here holds a default: a field left empty is not sent, and
// riccatid's default (shown as the placeholder) stands.
import {api} from './api.js';
import {h} from './dom.js';

let schemaCache = null;
// The schema is the same for every tenant and for the daemon's life: read once per page load.
export async function loadSchema(signal) {
  if (!schemaCache) schemaCache = await api('GET', '/schema', undefined, {signal});
  return schemaCache;
}

// The order groups are shown in, with their titles; a group the schema
// gains later is shown after these under its own name.
const kGroups = [['method', 'Method'], ['filter', 'Filter'], ['initial', 'Initial estimate'],
  ['parameters', 'Parameters'], ['optimiser', 'Optimiser'], ['integrator', 'Integrator'], ['data', 'Data']];

// What a field's text does not parse as, naming the setting and the text.
export class FormError extends Error {}

// The settings whose choice decides which others are shown: the method and the filter kind.
const kDriving = ['method', 'filter.kind'];

const fieldId = (s) => 'set-' + s.path.replaceAll('.', '-');
const applies = (list, value) => !list || list.length === 0 || list.includes(value);

// Comma-separated items (blanks around them ignored); empty text: none.
const items = (text) => text.split(',').map((x) => x.trim()).filter((x) => x !== '');

function number(text, what) {
  const t = text.trim();
  // Number() takes '' and ' ' as 0 and '0x10' as 16: only decimal notation here, as the CLI reads it.
  if (!/^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$/.test(t) && !/^[+-]?(inf|infinity|nan)$/i.test(t)) {
    throw new FormError(`${what}: "${t}" is not a number`);
  }
  const v = Number(/^[+-]?inf/i.test(t) ? t.replace(/inf(inity)?/i, 'Infinity') : t);
  // JSON has no infinity or NaN: protobuf's JSON mapping writes them as these strings.
  return Number.isFinite(v) ? v : (Number.isNaN(v) ? 'NaN' : (v > 0 ? 'Infinity' : '-Infinity'));
}

function count(text, what) {
  const t = text.trim();
  if (!/^\d+$/.test(t)) throw new FormError(`${what}: "${t}" is not a whole number (0 or more)`);
  return Number(t);
}

const numbers = (text, what) => items(text).map((x) => number(x, what));

// One value (the whole diagonal), a comma list (the diagonal) or rows
// separated by ';' (the full matrix, stored column-major), as the CLI reads them.
export function covariance(text, what) {
  if (!text.includes(';')) {
    const values = numbers(text, what);
    return values.length === 1 ? {scalar: values[0]} : {diagonal: {values}};
  }
  const rows = text.split(';').filter((r) => r.trim() !== '').map((r) => numbers(r, what));
  rows.forEach((r, i) => {
    if (r.length !== rows[0].length) {
      throw new FormError(`${what}: row ${i + 1} has ${r.length} value${r.length === 1 ? '' : 's'}, row 1 has ${rows[0].length}`);
    }
  });
  const values = [];
  for (let j = 0; j < rows[0].length; ++j) for (const r of rows) values.push(r[j]);
  return {full: {rows: rows.length, cols: rows[0].length, values}};
}

// NAME=LO:HI, either side may be empty (that side stays the model's).
function namedRange(item, what, form) {
  const m = /^([^=]+)=([^:]*):(.*)$/.exec(item);
  if (!m) throw new FormError(`${what}: "${item}" is not ${form}`);
  const out = {name: m[1].trim()};
  if (m[2].trim() !== '') out.lower = number(m[2], what);
  if (m[3].trim() !== '') out.upper = number(m[3], what);
  return out;
}

// The value of a setting's text, in the proto's JSON mapping; undefined when empty.
function parse(s, text, what) {
  if (text.trim() === '') return undefined;
  switch (s.kind) {
    case 'number': return number(text, what);
    case 'count': return count(text, what);
    case 'text': return text.trim();
    case 'numbers': return numbers(text, what);
    case 'names': return items(text);
    case 'covariance': return covariance(text, what);
    case 'initial_state':
      return text.trim() === 'first' ? {first_measurement: true} : {x0: numbers(text, what)};
    case 'bounds': return items(text).map((x) => namedRange(x, what, s.form || 'NAME=LO:HI'));
    case 'fixed':
      return items(text).map((x) => {
        const [name, value] = x.split('=');
        return value === undefined ? {name: name.trim()} : {name: name.trim(), value: number(value, what)};
      });
    default: throw new FormError(`${what}: a ${s.kind} setting has no field in the workbench`);
  }
}

// Sets obj[a][b][c] = value for path "a.b.c", merging into what is there
// (initial_state from --x0 and initial_state.estimate from --estimate-x0).
function put(obj, path, value) {
  const keys = path.split('.');
  let at = obj;
  for (const k of keys.slice(0, -1)) at = (at[k] = at[k] || {});
  const last = keys[keys.length - 1];
  at[last] = value !== null && typeof value === 'object' && !Array.isArray(value) && at[last]
    ? {...at[last], ...value} : value;
}

const kShortDefault = 20;

function input(s) {
  const id = fieldId(s);
  const common = {id, 'data-path': s.path, 'data-flag': s.flag, name: s.keyword};
  switch (s.kind) {
    case 'switch':
      return h('input', {...common, type: 'checkbox'});
    case 'choice':
      // The first option sends nothing: riccatid's default.
      return h('select', common, h('option', {value: ''}, s.default ? `default (${s.default})` : '—'),
        (s.choices || []).map((c) => h('option', {value: c}, c)));
    default: {
      // A default too long for the field is written under it (field()).
      const hint = s.default ? (s.default.length > kShortDefault ? 'riccatid\'s default' : `default: ${s.default}`)
        : (s.form || '');
      return h('input', {...common, type: 'text', size: s.kind === 'number' || s.kind === 'count' ? 14 : 28,
        placeholder: hint, title: s.default ? `default: ${s.default}` : hint, autocomplete: 'off', spellcheck: 'false'});
    }
  }
}

// {element, control, implicit}: the setting's part of the form, its input, and the box of its implicit value.
function field(s) {
  const control = input(s);
  const unit = s.unit ? ` [${s.unit}]` : '';
  // A names setting with an implicit value ("all") has a box for it, as the CLI's flag given alone.
  const implicit = s.kind === 'names' && s.implicit
    ? h('input', {type: 'checkbox', id: fieldId(s) + '-implicit', 'data-implicit': s.implicit,
      onchange: (e) => { control.disabled = e.target.checked; }})
    : null;
  const element = h('div', {class: 'setting', 'data-path': s.path, 'data-flag': s.flag},
    h('label', {for: fieldId(s), class: s.kind === 'switch' ? 'inline' : ''},
      s.kind === 'switch' ? control : null,
      h('code', {}, s.flag), ' ', s.help + unit),
    s.kind === 'switch' ? null
      : h('div', {class: 'row'}, control, implicit ? h('label', {class: 'inline'}, implicit, s.implicit) : null),
    s.default && s.default.length > kShortDefault && s.kind !== 'choice'
      ? h('div', {class: 'muted default'}, `default: ${s.default}`) : null);
  return {element, control, implicit};
}

// settingsForm(schema, 'IdentificationSpec') -> {element, update(), value()}.
// The method and the filter kind are settings too (paths "method" and
// "filter.kind"); what is shown follows their choice, or riccatid's default.
export function settingsForm(schema, request) {
  const settings = (schema.requests || {})[request] || [];
  const fields = new Map(settings.map((s) => [s.path, {s, ...field(s)}]));
  const groups = [...kGroups];
  for (const s of settings) {
    if (s.group && !groups.some(([g]) => g === s.group)) groups.push([s.group, s.group[0].toUpperCase() + s.group.slice(1)]);
  }
  const sets = groups.map(([g, title]) => {
    // The choices the others' showing follows (method, filter kind) first in their groups.
    const members = settings.filter((s) => (s.group || '') === g)
      .sort((a, b) => kDriving.includes(b.path) - kDriving.includes(a.path)).map((s) => fields.get(s.path).element);
    return members.length ? h('fieldset', {'data-group': g}, h('legend', {}, title), h('div', {class: 'settings'}, members)) : null;
  }).filter(Boolean);
  const element = h('div', {class: 'settings-form', 'data-request': request}, sets);

  const chosen = (path) => {
    const f = fields.get(path);
    return f ? f.control.value || f.s.default || '' : '';
  };
  const method = () => chosen(kDriving[0]);
  const filter = () => chosen(kDriving[1]);
  const shown = (s) => applies(s.methods, method()) && applies(s.filters, filter());

  function update() {
    for (const {s, element: e} of fields.values()) e.hidden = !shown(s);
    for (const set of sets) set.hidden = [...set.querySelectorAll('.setting')].every((e) => e.hidden);
  }
  for (const path of kDriving) {
    const f = fields.get(path);
    if (f) f.control.addEventListener('change', update);
  }

  // The request's settings in the proto's JSON mapping: only the fields
  // shown and filled. Throws a FormError naming the flag of text that does not parse.
  function value() {
    const out = {};
    for (const {s, control, implicit} of fields.values()) {
      if (!shown(s)) continue;
      let v;
      if (s.kind === 'switch') {
        v = control.checked ? true : undefined;
      } else if (s.kind === 'choice') {
        // The JSON mapping names an enum value by its proto name: the schema lists them beside the choices.
        v = control.value === '' ? undefined : (s.values || [])[s.choices.indexOf(control.value)];
        if (control.value !== '' && v === undefined) throw new FormError(`${s.flag}: riccatid's schema lists no JSON name for "${control.value}"`);
      } else if (implicit && implicit.checked) {
        v = [s.implicit];
      } else {
        v = parse(s, control.value, s.flag);
      }
      if (v !== undefined) put(out, s.path, v);
    }
    return out;
  }

  update();
  return {element, update, value, method, filter, shown};
}
