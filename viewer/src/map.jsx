// react-map-gl as streetscape.gl imports it, with StaticMap (and mapbox-gl, most of
// react-map-gl's weight) in a chunk of its own, loaded when a base map is drawn:
// without a map token, the page never loads it. build.mjs points `react-map-gl` here.
import React, {Suspense} from 'react';

export {default as Popup} from 'react-map-gl/dist/esm/components/popup';
export {default as _MapContext} from 'react-map-gl/dist/esm/components/map-context';

const LazyStaticMap = React.lazy(() => import('react-map-gl/dist/esm/components/static-map'));

export function StaticMap(props) {
  return (
    <Suspense fallback={null}>
      <LazyStaticMap {...props} />
    </Suspense>
  );
}
