// What the page's own URL says (which log to open, the viewer token) and what the
// server put in the page (its settings: the map token).

/** The settings the server wrote into the page (see xviz_server/viewer.py). */
function serverSettings() {
  const element = document.getElementById('xviz-settings');
  return element ? JSON.parse(element.textContent) : {};
}

// Where the viewer token is kept once it is out of the address bar, and the map token the server
// gave with it: this tab's session storage.
const TOKEN_KEY = 'xviz-server:viewer-token';
const MAP_TOKEN_KEY = 'xviz-server:map-token';

/** `key`'s value in this tab's session storage after storing `value` there (if given). */
function kept(key, value) {
  try {
    if (value === null) {
      return window.sessionStorage.getItem(key);
    }
    window.sessionStorage.setItem(key, value);
  } catch (error) {
    // Storage refused (a private mode, a policy): the value serves this page until it is left.
  }
  return value;
}

/**
 * The viewer token. One in the page's URL (`?token=`) is moved out of it at once, so that
 * the address bar, the history and a shared link do not show it, into this tab's session
 * storage, where a reload finds it.
 */
export function pageToken() {
  const query = new URLSearchParams(window.location.search);
  const token = query.get('token');
  if (token !== null) {
    query.delete('token');
    const rest = query.toString();
    window.history.replaceState(window.history.state, '', `${window.location.pathname}${rest ? `?${rest}` : ''}`);
  }
  return kept(TOKEN_KEY, token);
}

/**
 * The page's log, and the map token: the server gives it to a page loaded with the viewer
 * token, which a reloaded page no longer has in its address, so it is kept with the token.
 */
export function pageParams() {
  const query = new URLSearchParams(window.location.search);
  return {
    log: query.get('log'),
    time: seconds(query.get('t')),
    mapToken: kept(MAP_TOKEN_KEY, serverSettings().mapToken || null) || ''
  };
}

/** Seconds into the log that `t` asks for (`?t=12.5`), or null. */
function seconds(text) {
  const value = Number(text);
  return text !== null && text !== '' && Number.isFinite(value) && value >= 0 ? value : null;
}

/** The page's URL that opens `log` (or the list, for null), at `time` seconds from its start if given. */
export function pageUrl(log, time = null) {
  const query = new URLSearchParams();
  if (log) {
    query.set('log', log);
  }
  if (log && Number.isFinite(time)) {
    query.set('t', time.toFixed(1));
  }
  const text = query.toString();
  return text ? `?${text}` : window.location.pathname;
}

/** The server's WebSocket address: the page's own host and port. */
export function serverUrl() {
  const scheme = window.location.protocol === 'https:' ? 'wss' : 'ws';
  return `${scheme}://${window.location.host}/`;
}

/**
 * The address a Foxglove or Lichtblick user pastes to open `name` (a live feed if `live`):
 * "Open connection", "Foxglove WebSocket". The page's viewer token, if it has one, is in it:
 * those apps cannot send a header.
 */
export function foxgloveUrl(name, live, token) {
  const query = [live ? 'session_type=live' : null, `log=${encodeURIComponent(name).replace(/%2F/g, '/')}`];
  if (token) {
    query.push(`token=${encodeURIComponent(token)}`);
  }
  return `${serverUrl()}?${query.filter(Boolean).join('&')}`;
}

/**
 * The log `name` as an MCAP file served with byte ranges, which Foxglove and Lichtblick seek in
 * (they read only the chunks a seek needs): "Open file from URL", or their `ds=remote-file`.
 */
export function logFileUrl(name, token) {
  const url = `${window.location.protocol}//${window.location.host}/api/logs/${encodeURIComponent(name)}/file.mcap`;
  return token ? `${url}?token=${encodeURIComponent(token)}` : url;
}

/**
 * Foxglove's web app opening `url` as a Foxglove WebSocket connection, as the Foxglove SDK links it,
 * or as another of its data sources (`remote-file`: a file's URL).
 */
export function foxgloveAppUrl(url, source = 'foxglove-websocket') {
  return `https://app.foxglove.dev/?ds=${source}&ds.url=${encodeURIComponent(url)}`;
}

async function getJSON(path, token, params = {}) {
  const headers = token ? {Accept: 'application/json', Authorization: `Bearer ${token}`} : {Accept: 'application/json'};
  const text = new URLSearchParams(params).toString();
  try {
    return await fetch(text ? `${path}?${text}` : path, {headers});
  } catch (error) {
    throw new Error(`the server does not answer (${error.message})`);
  }
}

/**
 * A page of the catalog of logs, and on the first page the live feeds, from the server's JSON
 * API: `params` are its query (q, limit, cursor: see docs/catalog.md).
 */
export async function fetchCatalog(token, params = {}) {
  const response = await getJSON('/api/logs', token, params);
  if (!response.ok) {
    const text = (await response.text()).trim();
    throw new Error(`the server refused the catalog: ${response.status} ${text}`);
  }
  return response.json();
}

/** Whether the server's catalog has the log `name`. */
export async function hasLog(name, token) {
  return (await getJSON(`/api/logs/${name.split('/').map(encodeURIComponent).join('/')}`, token)).ok;
}
