// Node's Buffer, which @xviz/io uses to tell binary messages from text; bundlers
// of streetscape.gl's day supplied it to the browser, esbuild injects it from here.
export {Buffer} from 'buffer';
