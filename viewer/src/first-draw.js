// When the 3D view's first frame is on screen: deck.gl has drawn its layers and the GPU has
// run those commands. On a software renderer (SwiftShader) that takes longer than the whole
// way to the frame's data; the page holds back what the frame does not need until then.

/**
 * A promise that resolves once the GPU has run the commands of the first frame in which
 * `deck` drew layers (a fence put into the command stream after that frame, WebGL 2), or
 * once deck has drawn them (WebGL 1, which has no fences); never if deck is finalized first.
 */
export function firstDraw(deck) {
  return new Promise(resolve => {
    const gl = deck.animationLoop.gl;
    const fences = typeof WebGL2RenderingContext !== 'undefined' && gl instanceof WebGL2RenderingContext;
    let fence = null;
    const poll = () => {
      if (!deck.layerManager) {
        return; // finalized (the viewer closed) before it drew: never
      }
      if (fence) {
        if (gl.getSyncParameter(fence, gl.SYNC_STATUS) === gl.SIGNALED) {
          gl.deleteSync(fence);
          resolve();
          return;
        }
      } else if (deck.layerManager.getLayers().length > 0 && !deck.needsRedraw()) {
        // Drawn (this frame or an earlier one): nothing waits to be drawn.
        if (!fences) {
          resolve();
          return;
        }
        fence = gl.fenceSync(gl.SYNC_GPU_COMMANDS_COMPLETE, 0);
        gl.flush();
      }
      requestAnimationFrame(poll);
    };
    requestAnimationFrame(poll);
  });
}
