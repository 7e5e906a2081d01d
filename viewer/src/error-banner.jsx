import React from 'react';

/** An error, shown to the person at the top of the page. */
export default function ErrorBanner({message}) {
  return (
    <div
      role="alert"
      className="error"
      style={{padding: '8px 16px', background: '#fde2e1', color: '#8a1c12', borderBottom: '1px solid #f2b8b5'}}
    >
      {message}
    </div>
  );
}
