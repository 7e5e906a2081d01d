import React from 'react';
import {render} from 'react-dom';
import 'mapbox-gl/dist/mapbox-gl.css';
import './page.css';
import App from './app';
import {markOnce} from './timing';

markOnce('script');

render(<App />, document.getElementById('app'));
