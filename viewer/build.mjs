// Bundle the viewer page into ../xviz_server/viewer_static/ (or the folder given as
// the first argument): index.html, content-hashed JS and CSS, and a gzip and brotli
// copy of each asset for the server to send to clients that accept them.
import {build} from 'esbuild';
import {mkdir, readFile, rm, writeFile} from 'node:fs/promises';
import {basename, dirname, join, resolve} from 'node:path';
import {fileURLToPath} from 'node:url';
import {brotliCompressSync, constants, gzipSync} from 'node:zlib';

const here = dirname(fileURLToPath(import.meta.url));
const outdir = resolve(process.argv[2] || join(here, '..', 'xviz_server', 'viewer_static'));

await rm(outdir, {recursive: true, force: true});
await mkdir(outdir, {recursive: true});
const result = await build({
  entryPoints: [join(here, 'src', 'index.jsx')],
  bundle: true,
  minify: true,
  sourcemap: false,
  format: 'iife',
  target: ['es2019'],
  outdir,
  entryNames: 'viewer-[hash]',
  assetNames: 'asset-[hash]',
  metafile: true,
  logLevel: 'warning',
  alias: {assert: join(here, 'src', 'assert.js')},
  inject: [join(here, 'src', 'node-globals.js')],
  define: {'process.env.NODE_ENV': '"production"', global: 'globalThis'},
  loader: {'.png': 'file', '.svg': 'file', '.woff': 'file', '.woff2': 'file'},
});

const outputs = Object.keys(result.metafile.outputs).map(path => basename(path));
const script = outputs.find(name => name.endsWith('.js'));
const style = outputs.find(name => name.endsWith('.css'));
const template = await readFile(join(here, 'src', 'index.html'), 'utf8');
const html = template
  .replace('<!--style-->', style ? `<link rel="stylesheet" href="${style}">` : '')
  .replace('<!--script-->', `<script src="${script}" defer></script>`);
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
