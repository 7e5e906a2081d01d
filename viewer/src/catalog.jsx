import React from 'react';
import {fetchCatalog, foxgloveAppUrl, foxgloveUrl, logFileUrl} from './page';

/** Logs asked for a page. */
const PAGE = 100;
/** Milliseconds of typing quiet before a search is asked for. */
const SEARCH_DELAY = 250;

function duration(log) {
  if (!Number.isFinite(log.start_time) || !Number.isFinite(log.end_time)) {
    return '';
  }
  return `${(log.end_time - log.start_time).toFixed(1)} s`;
}

/** Put `text` on the clipboard: the Clipboard API where the page may use it, else the selected `input`'s copy. */
async function copy(text, input) {
  if (navigator.clipboard && window.isSecureContext) {
    await navigator.clipboard.writeText(text);
    return;
  }
  input.select();
  if (!document.execCommand('copy')) {
    throw new Error('copy refused');
  }
}

/**
 * The address a Foxglove or Lichtblick user pastes for one log, with a button that copies it; for a
 * log (not a live feed), also its `file`: the URL of the log as a file to seek in, and Foxglove's app opening it.
 */
class FoxgloveUrl extends React.Component {
  state = {copied: null};
  input = React.createRef();

  componentWillUnmount() {
    clearTimeout(this.timer);
  }

  _onCopy = () => {
    copy(this.props.url, this.input.current).then(
      () => this.setState({copied: 'Copied'}),
      () => this.setState({copied: 'Select and copy'})
    );
    clearTimeout(this.timer);
    this.timer = setTimeout(() => this.setState({copied: null}), 2000);
  };

  render() {
    const {url, file} = this.props;
    return (
      <span style={{display: 'flex', gap: 6, alignItems: 'center'}}>
        <input
          className="foxglove-url"
          readOnly
          value={url}
          aria-label="Foxglove WebSocket URL"
          onFocus={event => event.target.select()}
          style={{flex: 1, minWidth: 120, fontFamily: 'monospace', fontSize: 12}}
        />
        <button className="foxglove-copy" type="button" onClick={this._onCopy} title="Copy, then in Foxglove or Lichtblick: Open connection, Foxglove WebSocket">
          {this.state.copied || 'Copy'}
        </button>
        <a className="foxglove-open" href={foxgloveAppUrl(url)} target="_blank" rel="noopener noreferrer" title="Open in Foxglove's web app">
          app
        </a>
        {file && (
          <a className="foxglove-file" href={file} title="The log as a file to seek in: in Foxglove or Lichtblick, open this URL as a remote file">
            file
          </a>
        )}
        {file && (
          <a className="foxglove-open-file" href={foxgloveAppUrl(file, 'remote-file')} target="_blank" rel="noopener noreferrer" title="Open the file in Foxglove's web app, to seek in">
            app (file)
          </a>
        )}
      </span>
    );
  }
}

function Row({name, cells, onOpen, foxglove, file}) {
  const open = event => {
    event.preventDefault();
    onOpen(name);
  };
  return (
    <tr className="log" data-log={name}>
      <td>
        <a href={`?log=${encodeURIComponent(name)}`} onClick={open}>
          {name}
        </a>
      </td>
      {cells.map((cell, i) => (
        <td key={i}>{cell}</td>
      ))}
      <td>
        <FoxgloveUrl url={foxglove} file={file} />
      </td>
    </tr>
  );
}

function cells(log) {
  if (log.error) {
    return [`unreadable: ${log.error}`, '', '', ''];
  }
  if (log.indexed === false) {
    return [`${log.kind}, not indexed yet`, '', '', ''];
  }
  return [
    log.format,
    log.frames,
    duration(log),
    <span title={(log.streams || []).join('\n')}>{(log.streams || []).length}</span>
  ];
}

/**
 * The list of logs and live feeds, a page at a time; a click on a name opens it. Each row
 * shows the address that opens it in Foxglove or Lichtblick. `catalog` is
 * the first page, fetched by the page; a search (of names and descriptions) asks the server
 * for its own pages.
 */
export default class Catalog extends React.Component {
  constructor(props) {
    super(props);
    const {catalog} = props;
    this.state = {q: '', logs: catalog.logs || [], next: catalog.next || null, counts: catalog, loading: false, error: null};
    this.asked = 0; // answers to older questions are dropped
  }

  componentWillUnmount() {
    clearTimeout(this.timer);
    this.asked++;
  }

  _ask(params, append) {
    const asked = ++this.asked;
    this.setState({loading: true, error: null});
    fetchCatalog(this.props.token, {limit: PAGE, ...params}).then(
      page => {
        if (asked === this.asked) {
          const logs = append ? this.state.logs.concat(page.logs) : page.logs;
          this.setState({logs, next: page.next, counts: page, loading: false});
        }
      },
      error => asked === this.asked && this.setState({error: error.message, loading: false})
    );
  }

  _onSearch = event => {
    const q = event.target.value;
    this.setState({q});
    clearTimeout(this.timer);
    this.timer = setTimeout(() => this._ask(q.trim() ? {q: q.trim()} : {}, false), SEARCH_DELAY);
  };

  _onMore = () => {
    const q = this.state.q.trim();
    this._ask({...(q ? {q} : {}), cursor: this.state.next}, true);
  };

  render() {
    const {catalog, onOpen, token} = this.props;
    const {q, logs, next, counts, loading, error} = this.state;
    const live = q.trim() ? [] : catalog.live || [];
    const indexing = Number.isFinite(counts.found) && counts.indexed < counts.found;
    return (
      <div style={{padding: 24, maxWidth: 1100, margin: '0 auto'}}>
        <h1 style={{fontSize: 22}}>{catalog.server}</h1>
        <div style={{display: 'flex', gap: 16, alignItems: 'center', marginBottom: 12}}>
          <input
            className="catalog-search"
            type="search"
            placeholder="Search names and descriptions"
            value={q}
            onChange={this._onSearch}
            style={{flex: 1, padding: '6px 10px', fontSize: 15}}
          />
          <span className="catalog-count">
            {Number.isFinite(counts.found) &&
              (indexing ? `${counts.indexed} of ${counts.found} logs indexed` : `${counts.found} logs`)}
          </span>
        </div>
        {error && <p role="alert">{error}</p>}
        <table className="catalog" style={{borderCollapse: 'collapse', width: '100%', background: '#fff'}}>
          <thead>
            <tr style={{textAlign: 'left'}}>
              {['name', 'format', 'frames', 'duration', 'streams', 'Foxglove / Lichtblick'].map(title => (
                <th key={title} style={{padding: '6px 10px', borderBottom: '1px solid #ccc'}}>
                  {title}
                </th>
              ))}
            </tr>
          </thead>
          <tbody>
            {live.map(feed => (
              <Row
                key={`live:${feed.name}`}
                name={feed.name}
                cells={['live', '', feed.connected ? 'source connected' : 'waiting for a source', '']}
                onOpen={onOpen}
                foxglove={foxgloveUrl(feed.name, true, token)}
              />
            ))}
            {logs.map(log => (
              <Row key={log.name} name={log.name} cells={cells(log)} onOpen={onOpen} foxglove={foxgloveUrl(log.name, false, token)} file={logFileUrl(log.name, token)} />
            ))}
          </tbody>
        </table>
        {next && (
          <button className="catalog-more" type="button" disabled={loading} onClick={this._onMore} style={{marginTop: 12}}>
            More logs
          </button>
        )}
        {logs.length + live.length === 0 && !loading && (
          <p>{q.trim() ? 'No log matches this search.' : 'This server has no logs and no live feeds.'}</p>
        )}
      </div>
    );
  }
}
