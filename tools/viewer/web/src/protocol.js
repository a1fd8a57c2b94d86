// Decoding of the viewer's binary WebSocket messages (see tools/viewer/
// segment_watcher.h for the layout). Little-endian 4-byte words throughout.

export const MSG_TOPOLOGY = 1;
export const MSG_FRAME = 2;
const FRAME_HEADER_WORDS = 24;

export const FLAG_HAS_TOOL = 1;
export const FLAG_HAS_STRESS = 2;
export const FLAG_SHUTTING_DOWN = 8;
export const TOOL_PROBE = 1;
export const TOOL_GRASPER = 2;

/** Returns {kind, ...} for a binary message (ArrayBuffer), or null when malformed. */
export function decode(buffer) {
  if (buffer.byteLength < 8 || buffer.byteLength % 4 !== 0) return null;
  const u = new Uint32Array(buffer);
  if (u[0] === MSG_TOPOLOGY) {
    const triangleCount = u[4];
    if (u.length < 8 + 3 * triangleCount) return null;
    return {
      kind: MSG_TOPOLOGY,
      generation: u[1],
      vertexCount: u[3],
      triangleCount,
      tissueCount: u[5],
      indices: new Uint32Array(buffer, 32, 3 * triangleCount),
    };
  }
  if (u[0] === MSG_FRAME) {
    if (u.length < FRAME_HEADER_WORDS) return null;
    const f = new Float32Array(buffer);
    const v = u[3], c = u[4], p = u[5];
    const need = FRAME_HEADER_WORDS + 5 * v + 8 * p + 6 * c;
    if (u.length < need) return null;
    let at = FRAME_HEADER_WORDS * 4;
    const take = (n) => {
      const a = new Float32Array(buffer, at, n);
      at += 4 * n;
      return a;
    };
    return {
      kind: MSG_FRAME,
      seq: u[1],
      topologyGeneration: u[2],
      vertexCount: v,
      contactCount: c,
      primitiveCount: p,
      flags: u[6],
      toolType: u[7],
      simTime: f[8],
      maxDisplacement: f[9],
      maxStress: f[10],
      gripperOpening: f[11],
      toolPos: [f[12], f[13], f[14]],
      toolQuatWxyz: [f[15], f[16], f[17], f[18]],
      toolForce: [f[19], f[20], f[21]],
      stepMs: f[22],
      step: u[23],
      positions: take(3 * v),
      displacement: take(v),
      stress: take(v),
      primitives: take(8 * p),
      contactPoints: take(3 * c),
      contactForces: take(3 * c),
    };
  }
  return null;
}
