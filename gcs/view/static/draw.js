// What both pages draw (the live view, and the flight report's replay): one frame (gcs/view/scene.py's JSON) three
// ways, a 3D scene (three.js, shipped in vendor/), a north-up map and a table, in the swarm frame: north-east-down
// metres from the origin. The page that imports this module feeds it frames and trails; it fetches nothing itself,
// so it runs the same from the live server and inlined in a report file.
// window.swarmView exposes what the page shows (its scene's positions, each drone's state) for tests and tools.

export const COLOURS = {
  disarmed: "#9e9e9e", armed: "#43a047", avoiding: "#fb8c00", failsafe: "#e53935", lost: "#212121", external: "#8e24aa",
};

const toThree = (ned) => [ned[1], -ned[2], -ned[0]];  // three.js: x east, y up, z south

export function fmt(v, digits = 1) { return v === null || v === undefined ? "-" : typeof v === "number" ? v.toFixed(digits) : String(v); }

// The noun for a count of ``n``, agreeing with it: "1 drone", "2 drones", "0 drones".
export function nounFor(n, noun, plural = `${noun}s`) { return n === 1 ? noun : plural; }

export function escape(text) { return text.replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]); }

// A view of the page's elements (#view3d, #map, #drones, #details and the header's #time, #separation, ...):
// ``show(frame, trails)`` draws one frame; ``trails`` maps sysid to the drone's recent positions (oldest first).
// ``THREE`` and ``OrbitControls`` are the loaded three.js modules, or null for a page without WebGL.
export function createView(THREE, OrbitControls) {
  const view = { frame: null, trails: new Map(), selected: null, webgl: false, scene3d: null, frames: 0, detail: null };
  window.swarmView = {
    frame: () => view.frame,
    frames: () => view.frames,
    webgl: () => view.webgl,
    selected: () => view.selected,
    select: (sysid) => { view.selected = sysid; if (view.frame) show(view.frame, view.trails); },
    // Each drone where the page's own scene has it, back in the swarm frame (north, east, down), and its state.
    drones: () => Object.fromEntries([...(view.scene3d ? view.scene3d.bodies : mapBodies()).entries()].map(
      ([sysid, body]) => [sysid, { pos_ned_m: body.pos_ned_m, state: body.state, colour: COLOURS[body.state] }])),
  };

  function mapBodies() {  // without WebGL, the map's drawn positions stand for the scene
    const out = new Map();
    for (const d of view.frame ? view.frame.drones : []) {
      if (d.pos_ned_m) out.set(d.sysid, { pos_ned_m: d.pos_ned_m, state: d.state });
    }
    return out;
  }

  // ---- 3D --------------------------------------------------------------------------------------------------------
  function make3d() {
    if (!THREE) return;
    try {
      const box = document.getElementById("view3d");
      const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
      renderer.setSize(box.clientWidth, box.clientHeight);
      box.appendChild(renderer.domElement);
      const scene = new THREE.Scene();
      scene.background = new THREE.Color(0x15202b);
      const camera = new THREE.PerspectiveCamera(50, box.clientWidth / box.clientHeight, 0.1, 2000);
      camera.position.set(-18, 16, 22);
      const controls = new OrbitControls(camera, renderer.domElement);
      scene.add(new THREE.GridHelper(100, 100, 0x335544, 0x223322));
      scene.add(new THREE.HemisphereLight(0xffffff, 0x334433, 2.0));
      const bodies = new Map();
      const obstacles = new THREE.Group();
      scene.add(obstacles);
      view.scene3d = { renderer, scene, camera, controls, bodies, obstacles, obstaclesShown: -1 };
      view.webgl = true;
      new ResizeObserver(() => {
        renderer.setSize(box.clientWidth, box.clientHeight);
        camera.aspect = box.clientWidth / box.clientHeight;
        camera.updateProjectionMatrix();
      }).observe(box);
      renderer.setAnimationLoop(() => { controls.update(); renderer.render(scene, camera); });
    } catch (err) {
      console.warn("no 3D view:", err);
      document.getElementById("view3d").textContent = "3D view unavailable (WebGL): the map and the table still work.";
    }
  }

  function frameCamera(s, frame) {  // once, on the first frame with positions: look at the swarm from the south-west
    const points = frame.drones.filter((d) => d.pos_ned_m).map((d) => toThree(d.pos_ned_m));
    if (!points.length) return;
    const c = [0, 1, 2].map((k) => points.reduce((sum, p) => sum + p[k], 0) / points.length);
    const spread = Math.max(6, ...points.map((p) => Math.hypot(p[0] - c[0], p[2] - c[2])));
    s.controls.target.set(c[0], Math.max(c[1], 1), c[2]);
    s.camera.position.set(c[0] - 1.2 * spread, c[1] + 1.4 * spread, c[2] + 2.0 * spread);
    s.framed = true;
  }

  function update3d(frame) {
    const s = view.scene3d;
    if (!s) return;
    if (!s.framed) frameCamera(s, frame);
    const seen = new Set();
    for (const d of frame.drones) {
      if (!d.pos_ned_m) continue;
      seen.add(d.sysid);
      let body = s.bodies.get(d.sysid);
      if (!body) {
        const group = new THREE.Group();
        const material = new THREE.MeshLambertMaterial({ color: COLOURS[d.state] });
        const hull = new THREE.Mesh(new THREE.CylinderGeometry(0.35, 0.35, 0.12, 16), material);
        const nose = new THREE.Mesh(new THREE.ConeGeometry(0.1, 0.35, 8), material);
        nose.rotation.x = -Math.PI / 2;
        nose.position.z = -0.45;
        group.add(hull, nose);
        const trail = new THREE.Line(new THREE.BufferGeometry(), new THREE.LineBasicMaterial({ color: 0x88aacc }));
        const slot = new THREE.Mesh(new THREE.TorusGeometry(0.3, 0.02, 6, 24), new THREE.MeshBasicMaterial({ color: 0x66ccff }));
        slot.rotation.x = Math.PI / 2;
        s.scene.add(group, trail, slot);
        body = { group, material, trail, slot, state: d.state, pos_ned_m: d.pos_ned_m };
        s.bodies.set(d.sysid, body);
      }
      body.group.position.set(...toThree(d.pos_ned_m));
      body.group.rotation.y = d.heading_deg === null ? 0 : -d.heading_deg * Math.PI / 180;
      body.material.color.set(COLOURS[d.state]);
      body.state = d.state;
      body.pos_ned_m = d.pos_ned_m;
      const trail = view.trails.get(d.sysid) || [];
      body.trail.geometry.setFromPoints(trail.map((p) => new THREE.Vector3(...toThree(p))));
      body.slot.visible = d.slot_ned_m !== null;
      if (d.slot_ned_m) body.slot.position.set(...toThree(d.slot_ned_m));
    }
    for (const [sysid, body] of s.bodies) {
      if (!seen.has(sysid)) { s.scene.remove(body.group, body.trail, body.slot); s.bodies.delete(sysid); }
    }
    if (s.obstaclesShown !== frame.obstacles.length) {
      s.obstacles.clear();
      for (const o of frame.obstacles) {
        const material = new THREE.MeshLambertMaterial({ color: 0xaa7744 });
        const mesh = o.kind === "sphere"
          ? new THREE.Mesh(new THREE.SphereGeometry(o.radius_m, 20, 12), material)
          : new THREE.Mesh(new THREE.CylinderGeometry(o.radius_m, o.radius_m, o.height_m, 20), material);
        mesh.position.set(o.east_m, o.kind === "sphere" ? o.height_m : o.height_m / 2, -o.north_m);
        s.obstacles.add(mesh);
      }
      s.obstaclesShown = frame.obstacles.length;
    }
  }

  // ---- map, north up ---------------------------------------------------------------------------------------------
  function drawMap(frame) {
    const canvas = document.getElementById("map");
    const w = (canvas.width = canvas.clientWidth), h = (canvas.height = canvas.clientHeight);
    const ctx = canvas.getContext("2d");
    const points = [];
    for (const d of frame.drones) {
      if (d.pos_ned_m) points.push(d.pos_ned_m);
      if (d.home_ned_m) points.push(d.home_ned_m);
    }
    for (const o of frame.obstacles) points.push([o.north_m, o.east_m, 0]);
    if (!points.length) return;
    let [minN, maxN, minE, maxE] = [Infinity, -Infinity, Infinity, -Infinity];
    for (const p of points) { minN = Math.min(minN, p[0]); maxN = Math.max(maxN, p[0]); minE = Math.min(minE, p[1]); maxE = Math.max(maxE, p[1]); }
    const span = Math.max(maxN - minN, maxE - minE, 10) * 1.3;
    const scale = Math.min(w, h) / span, cN = (minN + maxN) / 2, cE = (minE + maxE) / 2;
    const xy = (n, e) => [w / 2 + (e - cE) * scale, h / 2 - (n - cN) * scale];
    ctx.strokeStyle = "#1f331f";
    const step = span > 60 ? 10 : 1;
    for (let g = Math.floor((cE - span) / step) * step; g < cE + span; g += step) { const [x] = xy(0, g); ctx.beginPath(); ctx.moveTo(x, 0); ctx.lineTo(x, h); ctx.stroke(); }
    for (let g = Math.floor((cN - span) / step) * step; g < cN + span; g += step) { const [, y] = xy(g, 0); ctx.beginPath(); ctx.moveTo(0, y); ctx.lineTo(w, y); ctx.stroke(); }
    ctx.fillStyle = "#ccc"; ctx.fillText(`N ↑   grid ${step} m`, 8, 14);
    for (const o of frame.obstacles) {
      const [x, y] = xy(o.north_m, o.east_m);
      ctx.fillStyle = "#aa7744"; ctx.beginPath(); ctx.arc(x, y, o.radius_m * scale, 0, 2 * Math.PI); ctx.fill();
    }
    for (const d of frame.drones) {
      if (d.home_ned_m) { const [x, y] = xy(d.home_ned_m[0], d.home_ned_m[1]); ctx.strokeStyle = "#777"; ctx.strokeRect(x - 3, y - 3, 6, 6); }
      const trail = view.trails.get(d.sysid) || [];
      ctx.strokeStyle = "#6688aa"; ctx.beginPath();
      trail.forEach((p, i) => { const [x, y] = xy(p[0], p[1]); if (i) ctx.lineTo(x, y); else ctx.moveTo(x, y); });
      ctx.stroke();
      if (d.slot_ned_m) { const [x, y] = xy(d.slot_ned_m[0], d.slot_ned_m[1]); ctx.strokeStyle = "#66ccff"; ctx.beginPath(); ctx.arc(x, y, 6, 0, 2 * Math.PI); ctx.stroke(); }
      if (!d.pos_ned_m) continue;
      const [x, y] = xy(d.pos_ned_m[0], d.pos_ned_m[1]);
      ctx.fillStyle = COLOURS[d.state]; ctx.strokeStyle = d.sysid === view.selected ? "#fff" : "#000";
      ctx.beginPath(); ctx.arc(x, y, 7, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
      if (d.heading_deg !== null) {
        const a = d.heading_deg * Math.PI / 180;
        ctx.strokeStyle = "#fff"; ctx.beginPath(); ctx.moveTo(x, y); ctx.lineTo(x + 12 * Math.sin(a), y - 12 * Math.cos(a)); ctx.stroke();
      }
      if (d.state === "lost") { ctx.strokeStyle = "#e53935"; ctx.beginPath(); ctx.moveTo(x - 7, y - 7); ctx.lineTo(x + 7, y + 7); ctx.moveTo(x + 7, y - 7); ctx.lineTo(x - 7, y + 7); ctx.stroke(); }
      ctx.fillStyle = "#fff"; ctx.fillText(String(d.sysid), x + 9, y - 8);
    }
    view.mapTransform = { cN, cE, scale, w, h };
  }

  // ---- table and details -----------------------------------------------------------------------------------------
  function drawTable(frame) {
    const body = document.querySelector("#drones tbody");
    const rows = frame.drones.map((d) => `<tr data-sysid="${d.sysid}" class="${d.sysid === view.selected ? "selected" : ""}">` +
      `<td>${d.sysid}</td><td class="state" style="color:${COLOURS[d.state] === "#212121" ? "#e53935" : COLOURS[d.state]}">${d.state}</td>` +
      `<td>${d.mode}</td><td>${d.armed ? "yes" : "no"}</td><td>${fmt(d.alt_m, 2)}</td>` +
      `<td>${d.battery === null ? "-" : Math.round(d.battery * 100) + " %"}</td><td>${fmt(d.link_age_s, 2)}</td>` +
      `<td>${d.text === null ? "" : escape(d.text)}</td></tr>`);
    body.innerHTML = rows.join("");
    const details = document.getElementById("details");
    const chosen = frame.drones.find((d) => d.sysid === view.selected);
    details.hidden = !chosen;
    if (chosen) {
      const text = details.querySelector("pre");
      text.textContent = detailText(chosen);
      if (view.detail) view.detail(chosen, details);
    }
  }

  function detailText(d) {
    const vec = (v, digits = 2) => (v ? v.map((x) => fmt(x, digits)).join(", ") : "-");
    return [
      `sysid ${d.sysid}: ${d.state}, ${d.mode}, ${d.armed ? "armed" : "disarmed"}`,
      `position N, E, D  ${vec(d.pos_ned_m)} m`,
      `velocity N, E, D  ${vec(d.vel_ned_mps)} m/s`,
      `heading ${fmt(d.heading_deg, 1)} deg, altitude ${fmt(d.alt_m, 2)} m`,
      `slot  ${vec(d.slot_ned_m)}`,
      `home  ${vec(d.home_ned_m)}`,
      `battery ${d.battery === null ? "-" : Math.round(d.battery * 100) + " %"}, link age ${fmt(d.link_age_s, 2)} s`,
      `last text: ${d.text === null ? "-" : d.text}`,
    ].join("\n");
  }

  document.querySelector("#drones tbody").addEventListener("click", (ev) => {
    const row = ev.target.closest("tr");
    if (!row) return;
    const sysid = Number(row.dataset.sysid);
    view.selected = view.selected === sysid ? null : sysid;
    if (view.frame) show(view.frame, view.trails);
  });

  document.getElementById("map").addEventListener("click", (ev) => {
    const t = view.mapTransform;
    if (!t || !view.frame) return;
    const rect = ev.target.getBoundingClientRect();
    let best = null, bestDist = 15;
    for (const d of view.frame.drones) {
      if (!d.pos_ned_m) continue;
      const x = t.w / 2 + (d.pos_ned_m[1] - t.cE) * t.scale, y = t.h / 2 - (d.pos_ned_m[0] - t.cN) * t.scale;
      const dist = Math.hypot(ev.clientX - rect.left - x, ev.clientY - rect.top - y);
      if (dist < bestDist) { best = d.sysid; bestDist = dist; }
    }
    view.selected = best;
    show(view.frame, view.trails);
  });

  function setText(id, text) {
    const el = document.getElementById(id);
    if (el) el.textContent = text;
  }

  // ---- one frame ---------------------------------------------------------------------------------------------------
  function show(frame, trails) {
    view.frame = frame;
    view.trails = trails;
    view.frames += 1;
    setText("time", fmt(frame.time_s, 1));
    setText("rtf", fmt(frame.realtime_factor, 2));
    setText("separation", fmt(frame.separation_m, 2));
    setText("min-separation", fmt(frame.min_separation_m, 2));
    const count = document.getElementById("count"), n = frame.drones.length;
    if (count) count.innerHTML = `<b>${n}</b> ${nounFor(n, "drone")}`;
    update3d(frame);
    drawMap(frame);
    drawTable(frame);
  }

  make3d();
  // ``onDetail(drone, element)``: called with the selected drone's details box after it is drawn (the live page
  // adds its camera image there).
  return { show, onDetail: (fn) => { view.detail = fn; } };
}
