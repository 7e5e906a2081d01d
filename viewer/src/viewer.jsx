import React from 'react';
import {
  LogViewer,
  PlaybackControl,
  StreamSettingsPanel,
  XVIZLiveLoader,
  XVIZPanel
} from 'streetscape.gl';
import ErrorBanner from './error-banner';
import {firstDraw} from './first-draw';
import {POINT_STREAMS} from './point-layer';
import ServerLoader from './server-loader';
import {pageUrl, serverUrl} from './page';
import {markOnce} from './timing';

const MAP_STYLE = 'mapbox://styles/mapbox/light-v9';
const CUSTOM_XVIZ_LAYERS = [POINT_STREAMS];
/** Milliseconds between updates of the link to the time shown. */
const LINK_INTERVAL = 500;
const SIDEBAR = {width: 340, display: 'flex', flexDirection: 'column', gap: 8, background: '#fff', padding: '0 12px 8px'};
const SECTION = {flex: '1 1 0', minHeight: 96, display: 'flex', flexDirection: 'column'};
const HEADING = {margin: '8px 0 4px', fontSize: 15};
const BODY = {flex: '1 1 0', minHeight: 0, overflowY: 'auto'};
// Tables fill their panel's box, and scroll in it (their default is 400 px, taller than the box).
const PANEL_PROPS = {table: {height: '100%'}, treetable: {height: '100%'}};

// The server's own message telling this page the session's level of detail (asked for with
// ?detail_notices=1); it is not XVIZ, so the loader's parser never sees it.
const DETAIL_NOTICE = '{"type":"xviz-server/detail"';

// The start of the server's xviz/error messages (always JSON text): the parser keeps only that one
// came ("Stream server error"), so the page reads the server's own words before it.
const SERVER_ERROR = '{"type":"xviz/error"';

/**
 * A WebSocket class that also reports every close to `onClose(event, opened)`, hands the
 * server's level-of-detail notices to `onDetail(data)` instead of the loader, and the text of
 * each xviz/error the server sends to `onServerError(message)` before the loader sees it.
 */
function watchedSocket(onClose, onDetail, onServerError) {
  return class WatchedSocket extends WebSocket {
    constructor(url, protocols) {
      super(url, protocols);
      let opened = false;
      this.addEventListener('open', () => {
        opened = true;
        markOnce('socket-open');
      });
      this.addEventListener('close', event => onClose(event, opened));
    }

    set onmessage(handler) {
      super.onmessage = event => {
        if (typeof event.data === 'string' && event.data.startsWith(DETAIL_NOTICE)) {
          onDetail(JSON.parse(event.data).data);
        } else {
          if (typeof event.data === 'string' && event.data.startsWith(SERVER_ERROR)) {
            onServerError(errorText(JSON.parse(event.data).data));
          }
          handler(event);
        }
      };
    }

    get onmessage() {
      return super.onmessage;
    }
  };
}

function errorText(error) {
  if (!error) {
    return 'unknown error';
  }
  if (typeof error === 'string') {
    return error;
  }
  return error.message || (error.data && error.data.message) || JSON.stringify(error);
}

function formatTimestamp(seconds) {
  return new Date(seconds * 1000).toISOString().slice(11, 23);
}

/**
 * The timeline's label for `seconds` after the start of a log of `duration` seconds: as many
 * decimals as its ticks (about twenty at most) need, so that no two read the same on a short
 * log; minutes and hours on long ones.
 */
export function formatTick(seconds, duration) {
  // Ticks are at least 0.05 of the log apart (1/20), a round step (1, 2 or 5 times a power of ten).
  const decimals = duration > 0 ? Math.min(3, Math.max(0, Math.ceil(-Math.log10(duration / 20) - 0.05))) : 0;
  if (duration < 60) {
    return `${seconds.toFixed(decimals)}\u00a0s`; // no break: the last label keeps its unit at the window's edge
  }
  const whole = Math.round(seconds);
  const pad = n => String(n).padStart(2, '0');
  const [h, m, s] = [Math.floor(whole / 3600), Math.floor(whole / 60) % 60, whole % 60];
  return duration < 3600 ? `${m}:${pad(s)}` : `${h}:${pad(m)}:${pad(s)}`;
}

/** The server's address of an MCAP file of the log `name` from `start` to `end` (the log's own seconds). */
export function exportUrl(name, start, end, token) {
  const query = new URLSearchParams({start: start.toFixed(3), end: end.toFixed(3)});
  if (token) {
    query.set('token', token);
  }
  return `/api/logs/${name.split('/').map(encodeURIComponent).join('/')}/export?${query}`;
}

function createLoader({name, live, token, onClose, onDetail, onServerError, drawn}) {
  const options = {
    // The loaders put it in the URL as it is; the server decodes the query.
    logGuid: encodeURIComponent(name),
    bufferLength: live ? 10 : 5, // seconds of log the page holds (and asks for at once)
    serverConfig: {
      serverUrl: serverUrl(),
      defaultLogLength: 30,
      queryParams: {detail_notices: 1, ...(token ? {token: encodeURIComponent(token)} : {})}
    },
    // Messages are parsed on the page's thread: a worker would first have to start and load
    // its own copy of the parser, which costs more than the first frames' parse.
    worker: false,
    WebSocketClass: watchedSocket(onClose, onDetail, onServerError)
  };
  // Every other option would be put in the WebSocket's URL: the first drawing is ServerLoader's own.
  return live ? new XVIZLiveLoader(options) : new ServerLoader(options, drawn);
}

/**
 * One log or live feed: the 3D view, playback, the stream list and the log's UI panels.
 * Until the 3D view's first frame is on screen, the page does nothing else it can put off:
 * the log's panels (plots, camera images, drawn by the same GPU) and the buffer of frames
 * around the first (ServerLoader's bufferAfter) wait for it.
 */
export default class Viewer extends React.Component {
  constructor(props) {
    super(props);
    this.state = {error: null, panels: [], drawn: false, linkTime: null, detail: null, range: null};
    const drawn = new Promise(resolve => {
      this._onDeckLoad = deck => firstDraw(deck).then(resolve);
    });
    drawn.then(() => {
      markOnce('first-draw');
      if (!this.closed) {
        this.setState({drawn: true});
        this._seekToLinkedTime();
      }
    });
    this.log = createLoader({
      ...props,
      drawn,
      onClose: this._onSocketClose,
      onDetail: this._onDetail,
      onServerError: message => {
        this.serverError = message;
      }
    });
    // The socket opens while React mounts the 3D view; nothing it receives is handled
    // before componentDidMount, which runs in this same task. Refusals are reported by
    // _onSocketClose as they happen; the loader gives up after a few.
    this.log.connect().catch(() => {});
  }

  componentDidMount() {
    this.log
      .on('ready', () => {
        markOnce('metadata');
        const metadata = this.log.getMetadata() || {};
        this.setState({panels: Object.keys(metadata.ui_config || {}), error: null});
      })
      .on('update', () => this.log.getCurrentFrame() && markOnce('first-frame')) // one the 3D view can draw
      .on('error', (eventType, error) => {
        // The loader calls back with (event type, payload).
        console.error('xviz-server viewer:', error); // eslint-disable-line no-console
        // The server's own words when it sent them (the parser keeps only "Stream server error").
        this.setState({error: this.serverError || errorText(error)});
        this.serverError = null;
      });
  }

  componentWillUnmount() {
    this.closed = true;
    clearInterval(this.linkTimer);
    this.log.close();
  }

  /** Once the log's start is drawn, go to the time the page's link asks for (`?t=`, seconds from the start). */
  _seekToLinkedTime() {
    const {time, live} = this.props;
    if (!live) {
      if (Number.isFinite(time) && Number.isFinite(this.log.getLogStartTime())) {
        this.log.seek(this.log.getLogStartTime() + time);
      }
      this.linkTimer = setInterval(this._updateLink, LINK_INTERVAL);
    }
  }

  /**
   * The link to the time shown now, in seconds from the log's start, and the time range an
   * export takes: from the time shown to the end of the log.
   */
  _updateLink = () => {
    const now = this.log.getCurrentTime();
    const start = this.log.getLogStartTime();
    const end = this.log.getLogEndTime();
    if (Number.isFinite(now) && Number.isFinite(start)) {
      const linkTime = Math.round(Math.max(0, now - start) * 10) / 10;
      if (linkTime !== this.state.linkTime) {
        this.setState({linkTime});
      }
      if (Number.isFinite(end) && end > now && (!this.state.range || this.state.range[0] !== now || this.state.range[1] !== end)) {
        this.setState({range: [now, end]});
      }
    }
  };

  _formatTick = x => {
    const start = this.log.getLogStartTime();
    return formatTick(x - start, this.log.getLogEndTime() - start);
  };

  _onDetail = detail => {
    if (!this.closed) {
      this.setState({detail});
    }
  };

  /** Ask the server for a level of detail, or 'auto' (chosen from the link). */
  _chooseDetail = event => {
    const message = {type: 'xviz/reconfigure', data: {update_type: 'DELTA', config_update: {profile: event.target.value}}};
    if (this.log.socket) {
      this.log.socket.send(JSON.stringify(message));
    }
  };

  _onSocketClose = (event, opened) => {
    if (this.closed) {
      return;
    }
    if (!opened) {
      this.setState({
        error:
          'The server refused the session or cannot be reached: it is gone, or its ' +
          '--viewer-token or --allowed-origins do not admit this page.'
      });
      return;
    }
    const reason = event.reason ? `: ${event.reason}` : '';
    this.setState({error: `The connection to the server closed (code ${event.code}${reason}).`});
  };

  render() {
    const {name, live, mapToken, onClose, token} = this.props;
    const {error, panels, drawn, linkTime, detail, range} = this.state;
    return (
      <div style={{display: 'flex', flexDirection: 'column', height: '100%'}}>
        <header style={{display: 'flex', gap: 16, alignItems: 'center', padding: '8px 16px', background: '#fff'}}>
          <a
            href="?"
            onClick={event => {
              event.preventDefault();
              onClose();
            }}
          >
            ← all logs
          </a>
          <strong className="log-name">{name}</strong>
          {live && <span className="live-badge">live</span>}
          {Number.isFinite(linkTime) && (
            <a className="time-link" href={pageUrl(name, linkTime)} title="A link that opens this log at this time">
              link at {linkTime.toFixed(1)} s
            </a>
          )}
          {range && (
            <a
              className="export"
              href={exportUrl(name, range[0], range[1], token)}
              download={`${name.replace(/\//g, '_')}.mcap`}
              title="An MCAP file of the log from the time shown to its end, for Foxglove or Lichtblick"
            >
              export {(range[1] - range[0]).toFixed(1)} s as MCAP
            </a>
          )}
          {detail && (
            <label className="detail" style={{marginLeft: 'auto'}}>
              detail{' '}
              <select value={detail.auto ? 'auto' : detail.level} onChange={this._chooseDetail}>
                <option value="auto">auto</option>
                {detail.levels.map(level => (
                  <option key={level} value={level}>
                    {level}
                  </option>
                ))}
              </select>{' '}
              <span className="detail-level">
                {detail.level}
                {detail.link_mbps !== null ? ` (link ${detail.link_mbps} Mbit/s)` : ''}
              </span>
            </label>
          )}
        </header>
        {error && <ErrorBanner message={error} />}
        <div style={{display: 'flex', flex: 1, minHeight: 0}}>
          <div style={{flex: 1, position: 'relative'}}>
            <LogViewer
              log={this.log}
              showMap={Boolean(mapToken)}
              mapboxApiAccessToken={mapToken}
              mapStyle={MAP_STYLE}
              showTooltip
              customXVIZLayers={CUSTOM_XVIZ_LAYERS}
              onDeckLoad={this._onDeckLoad}
            />
          </div>
          {/* Every panel and the stream list share the column's height, each scrolling in its own box. */}
          <aside className="sidebar" style={SIDEBAR}>
            {(drawn ? panels : []).map(panel => (
              <section key={panel} className="xviz-panel" style={SECTION}>
                <h3 style={HEADING}>{panel}</h3>
                <div className="panel-body" style={BODY}>
                  <XVIZPanel log={this.log} name={panel} componentProps={PANEL_PROPS} />
                </div>
              </section>
            ))}
            <section className="streams" style={SECTION}>
              <h3 style={HEADING}>Streams</h3>
              <div className="panel-body" style={BODY}>
                <StreamSettingsPanel log={this.log} />
              </div>
            </section>
          </aside>
        </div>
        {!live && (
          <div className="playback" style={{background: '#fff'}}>
            <PlaybackControl width="100%" log={this.log} formatTimestamp={formatTimestamp} formatTick={this._formatTick} />
          </div>
        )}
      </div>
    );
  }
}
