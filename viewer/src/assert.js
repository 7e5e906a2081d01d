// The browser stand-in for Node's `assert`, which streetscape.gl and deck.gl import.
export default function assert(condition, message) {
  if (!condition) {
    throw new Error(message || 'assertion failed');
  }
}
