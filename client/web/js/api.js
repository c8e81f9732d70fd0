// The JSON API (/api/v1/, riccatid's service/http/http_api.hpp): every call
// with "Authorization: Bearer <token>". The token lives in this tab's
// sessionStorage, never in a cookie or a URL.

const kTokenKey = 'riccati.token';

export function token() { return sessionStorage.getItem(kTokenKey) || ''; }
export function setToken(t) {
  if (t) sessionStorage.setItem(kTokenKey, t);
  else sessionStorage.removeItem(kTokenKey);
}

export class ApiError extends Error {
  constructor(status, message) {
    super(message);
    this.status = status;
  }
}

let onUnauthorized = () => {};
export function whenUnauthorized(f) { onUnauthorized = f; }

function headers(extra = {}) { return {Authorization: 'Bearer ' + token(), ...extra}; }

async function failure(res) {
  const text = await res.text();
  let message = text || res.statusText;
  try { message = JSON.parse(text).message || message; } catch (_) { /* not JSON */ }
  if (res.status === 401) onUnauthorized(message);
  return new ApiError(res.status, `${message} (HTTP ${res.status})`);
}

// api('GET', '/datasets'); api('POST', '/jobs/identification', spec);
// api('POST', '/datasets?name=x.csv', file, {raw: true}).
export async function api(method, path, body, {raw = false, signal} = {}) {
  const init = {method, headers: headers(), signal};
  if (body !== undefined) {
    init.body = raw ? body : JSON.stringify(body);
    init.headers['Content-Type'] = raw ? 'application/octet-stream' : 'application/json';
  }
  const res = await fetch('/api/v1' + path, init);
  if (!res.ok) throw await failure(res);
  const text = await res.text();
  return text ? JSON.parse(text) : {};
}

// Server-sent events, read with fetch (EventSource cannot send the token):
// onEvent(name, data) for each, until the stream ends or `signal` aborts.
export async function events(path, onEvent, signal) {
  const res = await fetch('/api/v1' + path, {headers: headers({Accept: 'text/event-stream'}), signal});
  if (!res.ok) throw await failure(res);
  const reader = res.body.getReader();
  const decoder = new TextDecoder();
  let buffer = '';
  for (;;) {
    const {value, done} = await reader.read();
    if (done) return;
    buffer += decoder.decode(value, {stream: true});
    let end;
    while ((end = buffer.indexOf('\n\n')) >= 0) {
      const block = buffer.slice(0, end);
      buffer = buffer.slice(end + 2);
      let name = '', data = '';
      for (const line of block.split('\n')) {
        if (line.startsWith('event: ')) name = line.slice(7);
        else if (line.startsWith('data: ')) data += line.slice(6);
      }
      if (name) onEvent(name, JSON.parse(data));
    }
  }
}
