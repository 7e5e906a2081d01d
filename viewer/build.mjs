// Bundle the viewer page into ../xviz_server/viewer_static/ (or the folder given as
// the first argument): index.html, content-hashed JS modules (the page, and chunks it
// loads when it needs them) and CSS, and a gzip and brotli copy of each asset for the
// server to send to clients that accept them.
import {build} from 'esbuild';
import {mkdir, readFile, rm, writeFile} from 'node:fs/promises';
import {basename, dirname, join, resolve} from 'node:path';
import {fileURLToPath} from 'node:url';
import {brotliCompressSync, constants, gzipSync} from 'node:zlib';

const here = dirname(fileURLToPath(import.meta.url));
const outdir = resolve(process.argv[2] || join(here, '..', 'xviz_server', 'viewer_static'));

/** `react-map-gl`, imported by streetscape.gl, resolves to src/map.jsx, which loads its map lazily. */
const lazyMap = {
  name: 'lazy-map',
  setup(build) {
    const shim = join(here, 'src', 'map.jsx');
    build.onResolve({filter: /^react-map-gl$/}, args => (args.importer === shim ? undefined : {path: shim}));
  }
};

await rm(outdir, {recursive: true, force: true});
await mkdir(outdir, {recursive: true});
const result = await build({
  entryPoints: [join(here, 'src', 'index.jsx')],
  bundle: true,
  minify: true,
  sourcemap: false,
  format: 'esm',
  splitting: true,
  target: ['es2020'],
  outdir,
  entryNames: 'viewer-[hash]',
  chunkNames: 'viewer-[hash]',
  assetNames: 'asset-[hash]',
  metafile: true,
  logLevel: 'warning',
  alias: {assert: join(here, 'src', 'assert.js')},
  plugins: [lazyMap],
  inject: [join(here, 'src', 'node-globals.js')],
  define: {'process.env.NODE_ENV': '"production"', global: 'globalThis'},
  loader: {'.png': 'file', '.svg': 'file', '.woff': 'file', '.woff2': 'file'},
});

const outputs = Object.keys(result.metafile.outputs).map(path => basename(path));
const entry = Object.entries(result.metafile.outputs).find(([, output]) => output.entryPoint);
const script = basename(entry[0]);
const style = entry[1].cssBundle && basename(entry[1].cssBundle);
const template = await readFile(join(here, 'src', 'index.html'), 'utf8');
const html = template
  .replace('<!--style-->', style ? `<link rel="stylesheet" href="${style}">` : '')
  .replace('<!--script-->', `<script type="module" src="${script}"></script>`);
await writeFile(join(outdir, 'index.html'), html);

for (const name of outputs) {
  const data = await readFile(join(outdir, name));
  await writeFile(join(outdir, `${name}.gz`), gzipSync(data, {level: 9}));
  await writeFile(
    join(outdir, `${name}.br`),
    brotliCompressSync(data, {params: {[constants.BROTLI_PARAM_QUALITY]: 11}})
  );
}
console.log(`viewer bundle in ${outdir}: ${outputs.join(', ')}`);
