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

// ---- the selected drone's camera: its newest image, asked for over MAVLink by the ground station while shown ----
const CAMERA_POLL_MS = 500;
const camera = { sysid: null, shown: null, timer: null };
window.swarmView.camera = () => camera.shown;

view.onDetail((drone, box) => {
  let figure = box.querySelector("figure");
  if (!figure) {
    figure = document.createElement("figure");
    figure.innerHTML = '<img class="camera" alt="what its camera sees"><figcaption>camera: asking...</figcaption>';
    box.prepend(figure);
  }
  if (camera.sysid !== drone.sysid) {
    camera.sysid = drone.sysid;
    camera.shown = null;
    figure.querySelector("img").removeAttribute("src");
    figure.querySelector("figcaption").textContent = "camera: asking...";
    clearTimeout(camera.timer);
    pollCamera(figure);
  }
});

async function pollCamera(figure) {
  const sysid = camera.sysid;
  if (sysid === null || window.swarmView.selected() !== sysid) { camera.sysid = null; return; }
  try {
    const response = await fetch(`/camera/${sysid}`, { cache: "no-store" });
    if (response.status === 200 && camera.sysid === sysid) {
      const img = figure.querySelector("img");
      const url = URL.createObjectURL(await response.blob());
      await new Promise((resolve) => { img.onload = resolve; img.onerror = resolve; img.src = url; });
      const time = Number(response.headers.get("X-Image-Time-S"));
      figure.querySelector("figcaption").textContent = `camera at t ${time.toFixed(1)} s (${img.naturalWidth}x${img.naturalHeight})`;
      camera.shown = { sysid, time_s: time, width: img.naturalWidth, height: img.naturalHeight };
    }
  } catch (err) {
    figure.querySelector("figcaption").textContent = `camera: ${err}`;
  }
  camera.timer = setTimeout(() => pollCamera(figure), CAMERA_POLL_MS);
}

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
