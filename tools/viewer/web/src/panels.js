// The side panel: figures, the rendered-force plot and the period-error histogram (2D canvas).

const WINDOW_S = 10;

export class ForcePlot {
  constructor(canvas) {
    this.canvas = canvas;
    this.sim = [];      // [t local s, |F| N]
    this.haptic = [];
  }
  addSim(t, f) { this.sim.push([t, f]); }
  addHaptic(t, f) { this.haptic.push([t, f]); }
  draw(now) {
    const cut = now - WINDOW_S;
    for (const s of [this.sim, this.haptic]) {
      let k = 0;
      while (k < s.length && s[k][0] < cut) ++k;
      if (k > 0) s.splice(0, k);
    }
    const g = this.canvas.getContext('2d');
    const w = this.canvas.width, h = this.canvas.height;
    g.clearRect(0, 0, w, h);
    let top = 0.1;
    for (const s of [this.sim, this.haptic]) for (const [, f] of s) top = Math.max(top, f);
    top = niceCeil(top);
    g.strokeStyle = '#3a414c';
    g.fillStyle = '#9fb0c4';
    g.font = '10px sans-serif';
    for (let i = 0; i <= 2; ++i) {
      const y = h - 12 - (i / 2) * (h - 20);
      g.beginPath(); g.moveTo(28, y); g.lineTo(w, y); g.stroke();
      g.fillText((top * i / 2).toPrecision(2), 0, y + 3);
    }
    const line = (s, colour) => {
      g.strokeStyle = colour;
      g.beginPath();
      s.forEach(([t, f], i) => {
        const x = 28 + (w - 28) * (t - cut) / WINDOW_S;
        const y = h - 12 - (f / top) * (h - 20);
        if (i === 0) g.moveTo(x, y); else g.lineTo(x, y);
      });
      g.stroke();
    };
    line(this.haptic, '#58b6ff');
    line(this.sim, '#ffb347');
  }
}

function niceCeil(x) {
  const e = Math.pow(10, Math.floor(Math.log10(x)));
  for (const m of [1, 2, 5, 10]) if (m * e >= x) return m * e;
  return 10 * e;
}

export function drawHistogram(canvas, hist) {
  const g = canvas.getContext('2d');
  const w = canvas.width, h = canvas.height;
  g.clearRect(0, 0, w, h);
  g.fillStyle = '#9fb0c4';
  g.font = '10px sans-serif';
  if (!hist || !hist.counts || hist.n === 0) {
    g.fillText('no haptic ticks (is haptic_server running?)', 8, h / 2);
    return;
  }
  const counts = hist.counts;
  const labels = hist.edges.map((e) => '≤' + e).concat(['>' + hist.edges[hist.edges.length - 1]]);
  const top = Math.max(1, ...counts);
  const bw = (w - 4) / counts.length;
  counts.forEach((c, i) => {
    // log scale so that rare late ticks stay visible
    const frac = c > 0 ? Math.log10(1 + c) / Math.log10(1 + top) : 0;
    const bh = frac * (h - 26);
    g.fillStyle = i >= counts.length - 3 ? '#e06c5c' : '#58b6ff';
    g.fillRect(2 + i * bw + 1, h - 14 - bh, bw - 2, bh);
    g.fillStyle = '#9fb0c4';
    g.save();
    g.translate(2 + i * bw + bw / 2, h - 2);
    g.textAlign = 'center';
    g.fillText(labels[i].replace('≤', ''), 0, 0);
    g.restore();
  });
  g.fillText(`p50 ${hist.p50.toFixed(1)}  p99 ${hist.p99.toFixed(1)}  max ${hist.max.toFixed(0)} µs  (${hist.n} ticks, log scale)`, 4, 10);
}
