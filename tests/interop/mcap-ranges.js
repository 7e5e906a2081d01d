// Read an MCAP file over HTTP by byte ranges with the published TypeScript reader
// (@mcap/core's McapIndexedReader), as the Foxglove and Lichtblick apps read a
// remote file: its size from a HEAD request, then each read a ranged GET (the
// answer must be 206 with the Content-Range asked for). zstd chunks are
// decompressed with fzstd.
//
//   node mcap-ranges.js URL START_NS END_NS [TOPIC,TOPIC...]
//
// It reads the file's summary, then the messages logged in [START_NS, END_NS] (of the topics given, else all), in
// the reader's order: log time.
// Output: {"size", "requests", "bytes" (body bytes received, every request),
// "chunks" (count in the chunk index), "channels": [topics],
// "messages": [{"topic", "logTime" (ns as a string), "bytes"}], "error"}.
'use strict';

const { McapIndexedReader } = require('@mcap/core');
const { decompress } = require('fzstd');

async function main() {
  const [url, start, end, topics] = process.argv.slice(2);
  let requests = 0;
  let bytes = 0;
  const head = await fetch(url, { method: 'HEAD' });
  requests += 1;
  if (head.status !== 200 || head.headers.get('accept-ranges') !== 'bytes') {
    throw new Error(`HEAD ${url}: ${head.status}, Accept-Ranges ${head.headers.get('accept-ranges')}`);
  }
  const size = BigInt(head.headers.get('content-length'));
  const readable = {
    size: async () => size,
    read: async (offset, length) => {
      const last = offset + length - 1n;
      const response = await fetch(url, { headers: { range: `bytes=${offset}-${last}` } });
      requests += 1;
      const body = new Uint8Array(await response.arrayBuffer());
      bytes += body.length;
      const expected = `bytes ${offset}-${last}/${size}`;
      if (response.status !== 206 || response.headers.get('content-range') !== expected) {
        throw new Error(`range ${offset}-${last}: ${response.status}, Content-Range ${response.headers.get('content-range')}`);
      }
      return body;
    },
  };
  const reader = await McapIndexedReader.Initialize({
    readable,
    decompressHandlers: { zstd: (data, decompressedSize) => decompress(data, new Uint8Array(Number(decompressedSize))) },
  });
  const messages = [];
  for await (const message of reader.readMessages({
    startTime: BigInt(start),
    endTime: BigInt(end),
    topics: topics ? topics.split(',') : undefined,
  })) {
    const channel = reader.channelsById.get(message.channelId);
    messages.push({ topic: channel.topic, logTime: message.logTime.toString(), bytes: message.data.length });
  }
  return {
    size: Number(size),
    requests,
    bytes,
    chunks: reader.chunkIndexes.length,
    channels: [...reader.channelsById.values()].map((channel) => channel.topic),
    messages,
  };
}

main().then(
  (result) => process.stdout.write(JSON.stringify(result)),
  (error) => {
    process.stdout.write(JSON.stringify({ error: String(error && error.stack || error) }));
    process.exitCode = 1;
  },
);
