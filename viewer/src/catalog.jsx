import React from 'react';

function duration(log) {
  if (!Number.isFinite(log.start_time) || !Number.isFinite(log.end_time)) {
    return '';
  }
  return `${(log.end_time - log.start_time).toFixed(1)} s`;
}

function Row({name, cells, onOpen}) {
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
    </tr>
  );
}

/** The list of logs and live feeds; a click on a name opens it. */
export default function Catalog({catalog, onOpen}) {
  const logs = catalog.logs || [];
  const live = catalog.live || [];
  return (
    <div style={{padding: 24, maxWidth: 1100, margin: '0 auto'}}>
      <h1 style={{fontSize: 22}}>{catalog.server}</h1>
      <table className="catalog" style={{borderCollapse: 'collapse', width: '100%', background: '#fff'}}>
        <thead>
          <tr style={{textAlign: 'left'}}>
            {['name', 'format', 'frames', 'duration', 'streams'].map(title => (
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
            />
          ))}
          {logs.map(log =>
            log.error ? (
              <Row key={log.name} name={log.name} cells={[`unreadable: ${log.error}`, '', '', '']} onOpen={onOpen} />
            ) : (
              <Row
                key={log.name}
                name={log.name}
                cells={[
                  log.format,
                  log.frames,
                  duration(log),
                  <span title={(log.streams || []).join('\n')}>{(log.streams || []).length}</span>
                ]}
                onOpen={onOpen}
              />
            )
          )}
        </tbody>
      </table>
      {logs.length + live.length === 0 && <p>This server has no logs and no live feeds.</p>}
    </div>
  );
}
