// Decode XVIZ messages with the published client (@xviz/parser 1.0.13) and
// print what it made of them, one JSON line per message, for the Python tests.
//
//   node xviz-decode.js [--full] FILE...
//
// Each line is {"file", "raw", "parsed"} or {"file", "error"}: "raw" is the
// envelope as @xviz/io unpacks it, "parsed" what parseXVIZMessageSync returns
// (what streetscape.gl draws from). Files are parsed in order, so a metadata
// message sets the XVIZ version for the updates after it, as in a session.
// Arrays print as plain.js shows them: typed arrays as {"$typed", "length",
// "sha256"} with their "values" when they hold at most 1024 (or with --full),
// else the first six as "head"; images and other byte arrays as {"$bytes", "sha256"}.
'use strict';

const fs = require('fs');
const {parseXVIZMessageSync} = require('@xviz/parser');
const {XVIZData} = require('@xviz/io');
const {plain} = require('./plain');

const args = process.argv.slice(2);
const full = args[0] === '--full';
const files = full ? args.slice(1) : args;

for (const file of files) {
  const buffer = fs.readFileSync(file);
  const data = buffer.buffer.slice(buffer.byteOffset, buffer.byteOffset + buffer.byteLength);
  const line = {file};
  try {
    const message = new XVIZData(data).message();
    line.raw = plain(message.message, full);
    parseXVIZMessageSync(
      data,
      result => {
        line.parsed = plain(result, full);
      },
      error => {
        line.error = String(error && error.stack ? error.stack : error);
      },
      {}
    );
  } catch (error) {
    line.error = String(error && error.stack ? error.stack : error);
  }
  process.stdout.write(JSON.stringify(line) + '\n');
}
