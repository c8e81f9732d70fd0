// Models: the loaded plugins with their states, parameters (default and
// bounds), inputs and outputs, and the check of their Jacobians.
import {api} from '../api.js';
import {clear, fmt, h, num} from '../dom.js';

export async function show(main, r, signal) {
  const models = (await api('GET', '/models', undefined, {signal})).models || [];
  const shown = r.id ? models.filter((m) => m.name === r.id) : models;
  clear(main, h('h1', {}, r.id ? `Model ${r.id}` : 'Models'), shown.map((m) => h('section', {class: 'panel', 'data-model': m.name},
    h('h2', {}, h('a', {href: '#/models/' + encodeURIComponent(m.name)}, m.name), ' ', h('span', {class: 'muted'}, m.version || '')),
    h('p', {}, m.description || ''),
    h('p', {}, h('b', {}, 'States: '), (m.stateNames || []).join(', ') || '–', ' · ',
      h('b', {}, 'Inputs: '), (m.inputNames || []).join(', ') || '–', ' · ',
      h('b', {}, 'Outputs: '), (m.outputNames || []).join(', ') || '–'),
    h('table', {},
      h('thead', {}, h('tr', {}, ['Parameter', 'Default', 'Lower', 'Upper'].map((c) => h('th', {}, c)))),
      h('tbody', {}, (m.paramNames || []).map((p, i) => h('tr', {}, h('th', {}, p),
        h('td', {class: 'num'}, fmt((m.thetaDefault || [])[i], 5)), h('td', {class: 'num'}, fmt((m.thetaLower || [])[i])),
        h('td', {class: 'num'}, fmt((m.thetaUpper || [])[i])))))),
    h('p', {class: 'muted'}, `Jacobians: f ${m.exactFJacobian ? 'exact' : 'finite differences'}, g ${m.exactGJacobian ? 'exact' : 'finite differences'}`,
      m.jacobianCheck && m.jacobianCheck.checked ? `; checked against finite differences: ${m.jacobianCheck.agrees ? 'agree' : 'DISAGREE'} (max error ${fmt(m.jacobianCheck.maxError, 2)})` : '',
      num(m.ndof) ? `; mechanical, ${num(m.ndof)} degrees of freedom` : ''),
    h('p', {}, h('a', {class: 'button', href: `#/identify?model=${encodeURIComponent(m.name)}`}, 'Identify with it')))));
}
