// User Timing marks of the way to the first drawn frame, for the browser's performance
// tools (and scripts/bench_viewer.py): each is set once, at its first occurrence.
const marked = new Set();

/** Mark `name` (prefixed "xviz:") in the page's performance timeline, the first time only. */
export function markOnce(name) {
  if (!marked.has(name)) {
    marked.add(name);
    performance.mark(`xviz:${name}`);
  }
}
