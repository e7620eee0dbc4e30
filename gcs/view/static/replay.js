// The flight report's replay (report.html): the recorded flight (gcs/view/replay.py's document) played back through
// draw.js, with a timeline (play, pause, scrub, speed), the flight's events as marks, and the separation computed
// here from the positions drawn. Positions are on the metrics' time grid and linear between its instants, as the
// metrics take them, and the contacts the drones reported count from the instant each arrived, as the metrics count
// them, so the minimum separation this page finds over the whole flight is metrics.json's. It opens
// where the whole swarm is known (the document's open_s: gcs/view/replay.py says why), the timeline reaching back to
// the first sample.
// window.swarmReplay exposes the replay's state and controls for tests and tools.

import { COLOURS, escape, fmt } from "./draw.js";

const TRAIL_S = 10;
const MARK_COLOURS = { avoidance: "#fb8c00", collision: "#ff1744", failsafe: "#e53935", loss: "#ffffff",
  regained: "#43a047", fault: "#ab47bc", policy: "#29b6f6", violation: "#ffeb3b" };
const SPEEDS = [0.25, 0.5, 1, 2, 4, 8, 16, 32];

export function startReplay(view, data) {
  const times = data.time_s;
  const T = times.length;
  const t0 = T ? times[0] : 0, t1 = T ? times[T - 1] : 0, hz = data.grid_hz;
  const opens = Math.min(Math.max(data.open_s ?? t0, t0), t1);  // every drone known from here on
  const drones = data.drones.map((d) => prepare(d));
  const external = (data.external || []).map((d) => prepare(d));  // attached vehicles: drawn, not in the separation
  const best = prefixMinimum();  // best[i]: the smallest separation over [t0, times[i]]
  // reported contacts, separations the positions drawn cannot show (one after the last sample counts at the end)
  const contacts = (data.contacts || []).map((c) => ({ ...c, time_s: Math.min(c.time_s, t1) }));
  const replay = { time: t0, playing: false, speed: 4, ended: false, separation: null, minSeparation: null };

  function prepare(d) {
    const pos = new Array(T), lastKnown = new Int32Array(T);
    let known = -1;
    for (let i = 0; i < T; i++) {
      pos[i] = d.north_m[i] === null ? null : [d.north_m[i], d.east_m[i], d.down_m[i]];
      if (pos[i]) known = i;
      lastKnown[i] = known;
    }
    const slot = (i) => d.slot_north_m[i] === null ? null : [d.slot_north_m[i], d.slot_east_m[i], d.slot_down_m[i]];
    return { ...d, pos, lastKnown, slot };
  }

  // ---- separation: the same candidates as gcs/record/metrics.py, from the positions drawn ---------------------------------
  function airborne(d, i) { return d.airborne[i] === 1 && d.pos[i] !== null; }
  function sub(a, b) { return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]; }
  function norm(v) { return Math.hypot(v[0], v[1], v[2]); }

  // The closest approach of drones a and b between instants i and i + 1, their relative motion linear, within the
  // first fraction ``upTo`` of the interval (null unless both are airborne at both ends).
  function closest(a, b, i, upTo) {
    if (!airborne(a, i) || !airborne(b, i) || !airborne(a, i + 1) || !airborne(b, i + 1)) return null;
    const r0 = sub(a.pos[i], b.pos[i]), dr = sub(sub(a.pos[i + 1], b.pos[i + 1]), r0);
    const dr2 = dr[0] * dr[0] + dr[1] * dr[1] + dr[2] * dr[2];
    const s = dr2 > 0 ? Math.min(Math.max(-(r0[0] * dr[0] + r0[1] * dr[1] + r0[2] * dr[2]) / dr2, 0), upTo) : 0;
    return norm([r0[0] + s * dr[0], r0[1] + s * dr[1], r0[2] + s * dr[2]]);
  }

  function prefixMinimum() {
    const out = new Float64Array(T).fill(Infinity);
    let running = Infinity;
    for (let i = 0; i < T; i++) {
      for (let a = 0; a < drones.length; a++) {
        for (let b = a + 1; b < drones.length; b++) {
          const A = drones[a], B = drones[b];
          if (airborne(A, i) && airborne(B, i)) running = Math.min(running, norm(sub(A.pos[i], B.pos[i])));
          if (i > 0) {
            const c = closest(A, B, i - 1, 1);
            if (c !== null) running = Math.min(running, c);
          }
        }
      }
      out[i] = running;
    }
    return out;
  }

  function contactsBy(t) {  // the closest contact reported at or before t
    let out = Infinity;
    for (const c of contacts) if (c.time_s <= t + 1e-9) out = Math.min(out, c.distance_m);
    return out;
  }

  // ---- one instant ---------------------------------------------------------------------------------------------
  function at(t) {
    const x = Math.min(Math.max((t - t0) * hz, 0), Math.max(T - 1, 0));
    const i = Math.min(Math.floor(x + 1e-9), Math.max(T - 2, 0));
    return [i, T > 1 ? Math.min(Math.max(x - i, 0), 1) : 0];
  }

  function position(d, i, f) {
    const p = d.pos[i], q = i + 1 < T ? d.pos[i + 1] : null;
    if (p && q) return [p[0] + f * (q[0] - p[0]), p[1] + f * (q[1] - p[1]), p[2] + f * (q[2] - p[2])];
    if (p && f === 0) return p;
    const k = f > 0 && q ? i + 1 : d.lastKnown[i] >= 0 ? d.lastKnown[i] : -1;
    return k >= 0 ? d.pos[k] : null;  // not heard now: where it was last seen
  }

  function lastBefore(list, t) {  // the last [time, value] pair at or before t, by bisection
    let lo = 0, hi = list.length - 1, found = null;
    while (lo <= hi) {
      const mid = (lo + hi) >> 1;
      if (list[mid][0] <= t + 1e-9) { found = list[mid]; lo = mid + 1; } else hi = mid - 1;
    }
    return found;
  }

  function frameAt(t) {
    const [i, f] = at(t);
    const k = f >= 0.5 && i + 1 < T ? i + 1 : i;  // the nearest instant, for what does not interpolate
    const out = [];
    const positions = [];
    for (const d of [...drones, ...external]) {
      const p = position(d, i, f);
      if (!p) continue;
      const state = lastBefore(d.states, t);
      const text = lastBefore(d.texts, t);
      if (!d.role) positions.push([d, p]);
      out.push({
        sysid: d.sysid, pos_ned_m: p, heading_deg: d.course_deg[k], alt_m: -p[2], home_ned_m: d.home_ned_m,
        slot_ned_m: d.slot(k), mode: d.mode[k] === null ? "-" : data.modes[d.mode[k]], armed: d.armed[k] === 1,
        state: state ? state[1] : "disarmed", battery: null, link_age_s: null, text: text ? text[1] : null,
      });
    }
    let now = Infinity, partial = Infinity;
    for (let a = 0; a < positions.length; a++) {
      for (let b = a + 1; b < positions.length; b++) {
        const [A, pa] = positions[a], [B, pb] = positions[b];
        const both = airborne(A, i) && airborne(B, i) && (f === 0 || (airborne(A, i + 1) && airborne(B, i + 1)));
        if (both) now = Math.min(now, norm(sub(pa, pb)));
        if (f > 0 && i + 1 < T) {
          const c = closest(A, B, i, f);
          if (c !== null) partial = Math.min(partial, c);
        }
      }
    }
    const sofar = Math.min(T ? best[i] : Infinity, partial, contactsBy(t));
    replay.separation = Number.isFinite(now) ? now : null;
    replay.minSeparation = Number.isFinite(sofar) ? sofar : null;
    return { time_s: t, drones: out, separation_m: replay.separation, min_separation_m: replay.minSeparation,
      realtime_factor: null, obstacles: data.obstacles };
  }

  function trailsAt(t) {
    const [i, f] = at(t);
    const trails = new Map();
    const from = Math.max(0, i - Math.round(TRAIL_S * hz));
    for (const d of [...drones, ...external]) {
      const trail = [];
      for (let k = from; k <= i; k++) if (d.pos[k]) trail.push(d.pos[k]);
      const p = position(d, i, f);
      if (p && f > 0) trail.push(p);
      trails.set(d.sysid, trail);
    }
    return trails;
  }

  // ---- timeline ------------------------------------------------------------------------------------------------
  const scrub = document.getElementById("scrub");
  const playButton = document.getElementById("play");
  const speedSelect = document.getElementById("speed");
  const marksCanvas = document.getElementById("marks");
  scrub.min = t0; scrub.max = t1; scrub.step = 1 / hz;
  speedSelect.innerHTML = SPEEDS.map((s) => `<option value="${s}"${s === replay.speed ? " selected" : ""}>${s}x</option>`).join("");

  function drawMarks() {
    const w = (marksCanvas.width = marksCanvas.clientWidth), h = (marksCanvas.height = marksCanvas.clientHeight);
    const ctx = marksCanvas.getContext("2d");
    const x = (t) => (t1 > t0 ? (t - t0) / (t1 - t0) : 0) * w;
    data.steps.forEach((s, n) => {
      ctx.fillStyle = n % 2 ? "#263238" : "#1c2a33";
      ctx.fillRect(x(s.start_s), 0, Math.max(x(s.end_s) - x(s.start_s), 1), h);
      ctx.fillStyle = "#9ab"; ctx.fillText(s.name, x(s.start_s) + 3, 11);
    });
    for (const m of data.marks) {
      ctx.fillStyle = MARK_COLOURS[m.kind] || "#fff";
      ctx.fillRect(x(m.time_s) - 1, 14, 3, h - 14);
    }
    ctx.fillStyle = "#fff"; ctx.fillRect(x(replay.time) - 1, 0, 2, h);
  }

  document.getElementById("events").innerHTML = data.marks.map((m) =>
    `<tr data-time="${m.time_s}" data-sysid="${m.sysid ?? ""}"><td>${fmt(m.time_s, 1)}</td>` +
    `<td style="color:${MARK_COLOURS[m.kind]}">${m.kind}</td><td>${m.sysid ?? "all"}</td><td>${escape(m.text)}</td></tr>`).join("");
  document.getElementById("events").addEventListener("click", (ev) => {
    const row = ev.target.closest("tr");
    if (!row) return;
    pause();
    if (row.dataset.sysid) window.swarmView.select(Number(row.dataset.sysid));
    seek(Number(row.dataset.time));
  });

  function render() {
    const frame = frameAt(replay.time);
    view.show(frame, trailsAt(replay.time));
    scrub.value = replay.time;
    document.getElementById("duration").textContent = fmt(t1, 1);
    playButton.textContent = replay.playing ? "pause" : "play";
    drawMarks();
  }

  function seek(t) {
    replay.time = Math.min(Math.max(Number(t), t0), t1);
    replay.ended = replay.time >= t1;
    render();
  }
  function play() {
    if (replay.time >= t1) replay.time = opens;  // again from where it opened, on the whole swarm
    replay.playing = true; replay.ended = false; last = null;
    render();
  }
  function pause() { replay.playing = false; render(); }
  function setSpeed(s) { replay.speed = Number(s); speedSelect.value = String(replay.speed); }

  let last = null;
  function tick(now) {
    if (replay.playing) {
      if (last !== null) {
        replay.time = Math.min(replay.time + ((now - last) / 1000) * replay.speed, t1);
        if (replay.time >= t1) { replay.playing = false; replay.ended = true; }
        render();
      }
      last = now;
    } else last = null;
    requestAnimationFrame(tick);
  }

  playButton.addEventListener("click", () => (replay.playing ? pause() : play()));
  scrub.addEventListener("input", () => { pause(); seek(scrub.value); });
  speedSelect.addEventListener("change", () => setSpeed(speedSelect.value));
  marksCanvas.addEventListener("click", (ev) => {
    const rect = marksCanvas.getBoundingClientRect();
    pause();
    seek(t0 + ((ev.clientX - rect.left) / rect.width) * (t1 - t0));
  });
  document.addEventListener("keydown", (ev) => {
    if (ev.target.closest && ev.target.closest("select, input")) return;
    if (ev.key === " ") { ev.preventDefault(); replay.playing ? pause() : play(); }
    else if (ev.key === "ArrowRight") seek(replay.time + 1);
    else if (ev.key === "ArrowLeft") seek(replay.time - 1);
  });
  new ResizeObserver(drawMarks).observe(marksCanvas);

  window.swarmReplay = {
    start: () => t0, opening: () => opens, end: () => t1, time: () => replay.time, playing: () => replay.playing,
    ended: () => replay.ended, speed: () => replay.speed, separation: () => replay.separation,
    minSeparation: () => replay.minSeparation,
    play, pause, seek, setSpeed, colours: () => COLOURS,
  };
  seek(opens);
  requestAnimationFrame(tick);
}
