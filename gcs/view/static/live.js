// The live view: frames from the ground station over /ws (JSON, gcs/view/scene.py), drawn by draw.js, with each
// drone's trail kept here from the frames as they come.
import { createView } from "./draw.js";

const TRAIL_POINTS = 100;  // at 10 frames a second: the last 10 s

async function loadThree() {
  try {
    const THREE = await import("./vendor/three/three.module.js");
    const { OrbitControls } = await import("./vendor/three/OrbitControls.js");
    return [THREE, OrbitControls];
  } catch (err) {
    console.warn("three.js did not load:", err);
    return [null, null];
  }
}

const [THREE, OrbitControls] = await loadThree();
const view = createView(THREE, OrbitControls);
const trails = new Map();

function receive(frame) {
  for (const d of frame.drones) {
    if (!d.pos_ned_m) continue;
    const trail = trails.get(d.sysid) || [];
    trail.push(d.pos_ned_m);
    if (trail.length > TRAIL_POINTS) trail.shift();
    trails.set(d.sysid, trail);
  }
  view.show(frame, trails);
}

function connect() {
  const link = document.getElementById("link");
  const ws = new WebSocket(`ws://${location.host}/ws`);
  ws.onopen = () => { link.textContent = "live"; link.className = "live"; };
  ws.onmessage = (ev) => receive(JSON.parse(ev.data));
  ws.onclose = () => { link.textContent = "disconnected: retrying"; link.className = "stale"; setTimeout(connect, 1000); };
}

connect();
