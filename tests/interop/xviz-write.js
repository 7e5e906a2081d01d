// Re-encode an XVIZ log directory with the published writers (@xviz/io 1.0.13),
// the way `xviz convert` does: each message is read with XVIZData and written
// with XVIZFormatWriter, once per output format.
//
//   node xviz-write.js SOURCE_DIR FORMAT:OUT_DIR...
//
// FORMAT is BINARY_PBE (XVIZProtobufWriter), BINARY_GLB (XVIZBinaryWriter) or
// JSON_STRING (XVIZJSONWriter). SOURCE_DIR holds 1-frame.* (the metadata) and
// 2-frame.* ... N-frame.* in any format @xviz/io reads; each OUT_DIR gets the
// same messages, and its 0-frame.json index, as the writer makes them.
'use strict';

const fs = require('fs');
const path = require('path');
const {XVIZData, XVIZFormatWriter, XVIZ_FORMAT} = require('@xviz/io');
const {FileSink} = require('@xviz/io/node');

const [source, ...targets] = process.argv.slice(2);
const FRAME = /^(\d+)-frame\.(json|glb|pbe)$/;

function read(file) {
  const buffer = fs.readFileSync(path.join(source, file));
  const data = buffer.buffer.slice(buffer.byteOffset, buffer.byteOffset + buffer.byteLength);
  return new XVIZData(data);
}

const files = new Map();
for (const name of fs.readdirSync(source)) {
  const match = FRAME.exec(name);
  if (match && Number(match[1]) >= 1) {
    files.set(Number(match[1]), name);
  }
}
const numbers = Array.from(files.keys()).sort((a, b) => a - b);

for (const target of targets) {
  const [format, directory] = target.split(/:(.*)/s);
  if (!XVIZ_FORMAT[format]) {
    throw new Error(`unknown format ${format}`);
  }
  fs.mkdirSync(directory, {recursive: true});
  const writer = new XVIZFormatWriter(new FileSink(directory), {format: XVIZ_FORMAT[format]});
  for (const number of numbers) {
    const data = read(files.get(number));
    if (number === 1) {
      writer.writeMetadata(data);
    } else {
      writer.writeMessage(number - 2, data);
    }
  }
  writer.close();
}
