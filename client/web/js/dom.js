// Building the page: elements and text nodes only. User data (names of
// datasets, messages) reaches the page as text, never as HTML.

// h('td', {class: 'num'}, '1.5') -> <td class="num">1.5</td>. Children are
// nodes, or anything else made text.
export function h(tag, props = {}, ...children) {
  const el = document.createElement(tag);
  for (const [key, value] of Object.entries(props || {})) {
    if (value === undefined || value === null || value === false) continue;
    if (key === 'class') el.className = value;
    else if (key.startsWith('on') && typeof value === 'function') el.addEventListener(key.slice(2), value);
    else if (key === 'value') el.value = value;
    else if (key === 'checked') el.checked = !!value;
    else el.setAttribute(key, value === true ? '' : String(value));
  }
  append(el, children);
  return el;
}

function append(el, children) {
  for (const c of children.flat(Infinity)) {
    if (c === undefined || c === null || c === false) continue;
    el.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
}

export function clear(el, ...children) {
  el.replaceChildren();
  append(el, children);
  return el;
}

// Numbers as the API gives them (protobuf's JSON: 64-bit integers and
// NaN/Infinity as strings).
export function num(v) {
  if (v === undefined || v === null || v === '') return NaN;
  return typeof v === 'number' ? v : Number(v);
}

export function fmt(v, digits = 4) {
  const x = num(v);
  if (Number.isNaN(x)) return '–';
  if (!Number.isFinite(x)) return x > 0 ? '∞' : '−∞';
  if (x === 0) return '0';
  const a = Math.abs(x);
  return a >= 1e5 || a < 1e-3 ? x.toExponential(digits - 1) : Number(x.toPrecision(digits)).toString();
}

// An interval "lo … hi" with enough significant digits to read its width to
// two digits (at least `digits`): 0.13412 … 0.13418, not 0.1341 … 0.1341.
export function fmtInterval(lo, hi, digits = 4) {
  const a = num(lo), b = num(hi);
  if (!Number.isFinite(a) || !Number.isFinite(b) || a === b) return `${fmt(a, digits)} … ${fmt(b, digits)}`;
  const scale = Math.max(Math.abs(a), Math.abs(b));
  const needed = Math.floor(Math.log10(scale)) - Math.floor(Math.log10(Math.abs(b - a))) + 2;
  const d = Math.min(15, Math.max(digits, needed));
  return `${fmt(a, d)} … ${fmt(b, d)}`;
}

// Tick labels that differ: fixed decimals from the ticks' spacing (uPlot's
// default keeps 3 decimals, so ticks 0.13405, 0.1341, 0.13415 all read
// 0.134), exponents for very large or small values; more digits if any two
// still read the same.
export function tickLabels(values, increment) {
  const finite = values.filter(Number.isFinite);
  const big = finite.some((v) => Math.abs(v) >= 1e6);
  const small = finite.length > 0 && finite.every((v) => v === 0 || Math.abs(v) < 1e-3);
  const step = Math.abs(num(increment)) || 1;
  let decimals = Math.max(0, Math.ceil(-Math.log10(step) - 1e-9));
  const label = (v, n) => {
    if (!Number.isFinite(v)) return '';
    if (big || small) return v === 0 ? '0' : v.toExponential(Math.min(14, n));
    return v.toFixed(Math.min(15, n));
  };
  if (big || small) {
    const scale = Math.max(...finite.map((v) => Math.abs(v)).filter((v) => v > 0), step);
    decimals = Math.max(1, Math.ceil(Math.log10(scale / step) - 1e-9));
  }
  for (let n = decimals; n <= decimals + 6; ++n) {
    const out = values.map((v) => label(v, n));
    if (new Set(out).size === out.length) return out.map((t) => (t === '-0' ? '0' : t));
  }
  return values.map((v) => label(v, decimals + 6));
}

export function when(ts) {
  if (!ts) return '';
  const d = new Date(ts);
  return Number.isNaN(d.getTime()) || d.getTime() <= 0 ? '' : d.toLocaleString();
}

// Row i of a column-major v1.Matrix {rows, cols, values}.
export function row(m, i) {
  if (!m || !m.values) return [];
  const rows = num(m.rows), cols = num(m.cols), out = new Array(cols);
  for (let j = 0; j < cols; ++j) out[j] = num(m.values[i + j * rows]);
  return out;
}

export function at(m, i, j) { return num(m.values[i + j * num(m.rows)]); }

// "FILTER_KIND_EKF" -> "EKF"
export function enumName(v, prefix) { return String(v || '').replace(prefix, ''); }
// An enum value as people read it, the default riccatid takes (`fallback`)
// where the request left it unspecified: "OE", or "FILTER" for
// IDENTIFICATION_METHOD_UNSPECIFIED.
export function enumOrDefault(v, prefix, fallback) {
  return !v || v === `${prefix}UNSPECIFIED` ? fallback : enumName(v, prefix);
}

export function errorBox(e) { return h('p', {class: 'error'}, String(e && e.message ? e.message : e)); }
