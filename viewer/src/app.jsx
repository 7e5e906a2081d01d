import React from 'react';
import Catalog from './catalog';
import ErrorBanner from './error-banner';
import Viewer from './viewer';
import {fetchCatalog, hasLog, pageParams, pageToken, pageUrl} from './page';
import {markOnce} from './timing';

/** The catalog, or the log the page's URL names. */
export default class App extends React.Component {
  constructor(props) {
    super(props);
    this.state = {...pageParams(), token: pageToken(), catalog: null, error: null, known: {}};
  }

  componentDidUpdate() {
    this._check();
  }

  /** Ask the server whether the log the URL names exists, when the first page does not show it. */
  _check() {
    const {catalog, log, known, token} = this.state;
    if (!catalog || !log || log in known || this._live(log) || (catalog.logs || []).some(entry => entry.name === log)) {
      return;
    }
    this.setState({known: {...known, [log]: null}});
    hasLog(log, token).then(
      found => this.setState(state => ({known: {...state.known, [log]: found}})),
      () => this.setState(state => ({known: {...state.known, [log]: true}})) // the session will say
    );
  }

  _live(log) {
    return (this.state.catalog.live || []).some(feed => feed.name === log);
  }

  componentDidMount() {
    window.addEventListener('popstate', this._onPopState);
    fetchCatalog(this.state.token).then(
      catalog => {
        markOnce('catalog');
        this.setState({catalog});
      },
      error => this.setState({error: error.message})
    );
  }

  componentWillUnmount() {
    window.removeEventListener('popstate', this._onPopState);
  }

  _onPopState = () => {
    const {log, time} = pageParams();
    this.setState({log, time});
  };

  _open = log => {
    window.history.pushState(null, '', pageUrl(log));
    this.setState({log, time: null});
  };

  render() {
    const {catalog, error, log, time, known, token, mapToken} = this.state;
    if (error) {
      return <ErrorBanner message={error} />;
    }
    if (!catalog) {
      return <p style={{padding: 24}}>Loading the catalog…</p>;
    }
    if (!log) {
      return <Catalog catalog={catalog} token={token} onOpen={this._open} />;
    }
    const live = this._live(log);
    const listed = live || (catalog.logs || []).some(entry => entry.name === log);
    if (!listed && known[log] !== false && known[log] !== true) {
      return <p style={{padding: 24}}>Looking for {log}…</p>;
    }
    if (!listed && known[log] === false) {
      return (
        <div>
          <ErrorBanner message={`This server has no log or live feed named "${log}".`} />
          <Catalog catalog={catalog} token={token} onOpen={this._open} />
        </div>
      );
    }
    return (
      <Viewer
        key={log}
        name={log}
        live={live}
        time={time}
        token={token}
        mapToken={mapToken}
        onClose={() => this._open(null)}
      />
    );
  }
}
