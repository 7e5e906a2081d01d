import React from 'react';
import Catalog from './catalog';
import ErrorBanner from './error-banner';
import Viewer from './viewer';
import {fetchCatalog, pageParams, pageToken, pageUrl} from './page';
import {markOnce} from './timing';

/** The catalog, or the log the page's URL names. */
export default class App extends React.Component {
  constructor(props) {
    super(props);
    this.state = {...pageParams(), token: pageToken(), catalog: null, error: null};
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

  _onPopState = () => this.setState({log: pageParams().log});

  _open = log => {
    window.history.pushState(null, '', pageUrl(log));
    this.setState({log});
  };

  render() {
    const {catalog, error, log, token, mapToken} = this.state;
    if (error) {
      return <ErrorBanner message={error} />;
    }
    if (!catalog) {
      return <p style={{padding: 24}}>Loading the catalog…</p>;
    }
    if (!log) {
      return <Catalog catalog={catalog} onOpen={this._open} />;
    }
    const live = (catalog.live || []).some(feed => feed.name === log);
    if (!live && !(catalog.logs || []).some(entry => entry.name === log)) {
      return (
        <div>
          <ErrorBanner message={`This server has no log or live feed named "${log}".`} />
          <Catalog catalog={catalog} onOpen={this._open} />
        </div>
      );
    }
    return (
      <Viewer
        key={log}
        name={log}
        live={live}
        token={token}
        mapToken={mapToken}
        onClose={() => this._open(null)}
      />
    );
  }
}
