// brdfd's page: the daemon's devices, a capture started from a material preset and followed
// live from its event stream, and the stored sessions with their reports. Plain DOM, no
// libraries, nothing fetched from outside the daemon. Text from the daemon is only ever set
// as textContent, never parsed as HTML.
"use strict";

const $ = (id) => document.getElementById(id);
let following = null; // { id, source }

class Unauthorized extends Error {}

async function api(path, options = {}) {
  const response = await fetch("/api/v1" + path, { credentials: "same-origin", ...options });
  if (response.status === 401) {
    $("app").hidden = true;
    $("login").hidden = false;
    throw new Unauthorized("sign in first");
  }
  const body = await response.json().catch(() => ({}));
  if (!response.ok) {
    throw new Error(body.message || `${response.status} ${response.statusText}`);
  }
  return body;
}

function post(path, body) {
  return api(path, {
    method: "POST",
    headers: { "Content-Type": "application/json" },
    body: JSON.stringify(body || {}),
  });
}

function el(tag, text, attributes = {}) {
  const e = document.createElement(tag);
  if (text !== undefined && text !== null) e.textContent = String(text);
  for (const [k, v] of Object.entries(attributes)) e.setAttribute(k, v);
  return e;
}

function row(cells) {
  const tr = el("tr");
  for (const c of cells) {
    const td = el("td");
    if (c instanceof Node) td.append(c);
    else td.textContent = c ?? "";
    tr.append(td);
  }
  return tr;
}

// Errors show under the capture form, where the user just acted, and are scrolled to; before
// the page is shown (the daemon unreachable), in the header.
function showError(e) {
  if (e instanceof Unauthorized) return;
  if ($("app").hidden) {
    $("health").textContent = String(e.message || e);
    $("health").className = "failed";
    return;
  }
  const box = $("error");
  box.textContent = String(e.message || e);
  box.hidden = false;
  box.scrollIntoView({ block: "nearest" });
}

// A background refresh that fails (the daemon restarting, the network gone) says so in the
// header, without moving the page or replacing what the user's own action was told.
function showStatus(e) {
  if (e instanceof Unauthorized) return;
  $("health").textContent = `cannot reach the daemon: ${e.message || e}`;
  $("health").className = "failed";
}

function clearError() {
  $("error").textContent = "";
  $("error").hidden = true;
}

// What a session's state reads as in the list: a running capture says so, with a spinner.
function stateCell(s) {
  if (!s.running) return el("span", s.state, { class: `state-${s.state}` });
  const span = el("span", null, { class: "state-running" });
  span.append(el("span", null, { class: "spinner", "aria-hidden": "true" }), `${s.state}…`);
  return span;
}

async function refreshHealth() {
  const h = await api("/health");
  $("health").className = "";
  $("health").textContent =
    `${h.software}; ${h.rig.simulated ? "simulated rig" : "hardware rig"}; ` +
    (h.busy ? `capturing ${h.busy}` : "idle");
  $("size-field").hidden = !h.rig.simulated;
  return h;
}

async function refreshDevices() {
  const body = $("devices").tBodies[0];
  const devices = await api("/devices");
  body.replaceChildren(
    ...devices.map((d) =>
      row([d.role, d.identity || d.selector, d.state, d.last_error || ""])
    )
  );
}

function resultLinks(id) {
  const span = el("span");
  const base = `/api/v1/sessions/${encodeURIComponent(id)}/result`;
  for (const [file, label] of [
    ["report.html", "report"],
    ["compare.png", "photo vs estimate"],
    ["preview.png", "sphere"],
    ["", "coefficients"],
  ]) {
    const a = el("a", label, { href: file ? `${base}/${file}` : base, target: "_blank" });
    span.append(a, " ");
  }
  // The export in 3D, on the daemon's viewer page.
  const viewer = `/viewer.html?session=${encodeURIComponent(id)}`;
  span.append(el("a", "3D view", { href: viewer, target: "_blank" }), " ");
  return span;
}

// Answers can come back out of order (a phase's refresh, the timer's, the finish's): only the
// latest request's answer is shown.
let sessionsAsked = 0;

async function refreshSessions() {
  const asked = ++sessionsAsked;
  const sessions = await api("/sessions");
  if (asked !== sessionsAsked) return;
  const body = $("sessions").tBodies[0];
  body.replaceChildren(
    ...sessions.reverse().map((s) => {
      let action = "";
      if (!s.running && (s.state === "failed" || s.state === "created")) {
        action = el("button", "Resume", { type: "button" });
        action.addEventListener("click", () => resume(s.id).catch(showError));
      }
      return row([
        s.id,
        stateCell(s),
        s.material,
        s.created,
        s.state === "done" ? resultLinks(s.id) : "",
        action,
      ]);
    })
  );
}

async function loadMaterials() {
  const m = await api("/materials");
  $("material").replaceChildren(...m.presets.map((p) => el("option", p, { value: p })));
}

// A phase's row: its name, a bar, and its time. While it runs the time is the elapsed time
// beside a spinner, so a long phase (a slow camera, an estimate) is visibly alive.
function phaseRow(phases, name) {
  let p = phases.get(name);
  if (!p) {
    const bar = el("progress", null, { max: "1", value: "0" });
    const time = el("span", "", { class: "time" });
    const div = el("div", null, { class: "phase running" });
    div.append(el("span", null, { class: "spinner", "aria-hidden": "true" }), el("span", name), bar, time);
    $("phases").append(div);
    p = { div, bar, time, since: performance.now() };
    phases.set(name, p);
  }
  return p;
}

function endPhase(p, seconds) {
  p.div.classList.remove("running");
  p.div.classList.add("done");
  p.bar.value = p.bar.max;
  p.time.textContent = `${seconds.toFixed(2)} s`;
}

function tickPhases(phases) {
  const now = performance.now();
  for (const p of phases.values()) {
    if (p.div.classList.contains("running")) {
      p.time.textContent = `${Math.floor((now - p.since) / 1000)} s`;
    }
  }
}

// The operator's turn is a phase of its own: the capture waits on the bench, not on brdfd.
const WAITING = (view) => `view ${view}: waiting for the turn`;

function follow(id) {
  if (following) following.source.close();
  $("run").hidden = false;
  $("run-title").textContent = `session ${id}`;
  $("phases").replaceChildren();
  $("messages").replaceChildren();
  $("outcome").textContent = "";
  $("outcome").className = "";
  $("cancel").hidden = false;
  $("cancel").disabled = false;
  $("cancel").textContent = "Cancel it";
  $("start").disabled = true;
  const phases = new Map();
  const source = new EventSource(`/api/v1/sessions/${encodeURIComponent(id)}/events`);
  const ticker = setInterval(() => tickPhases(phases), 500);
  following = { id, source, ticker };
  let waiting = null;
  source.onmessage = (message) => {
    const e = JSON.parse(message.data);
    // Any later event means the capture went on: the object was turned.
    $("continue").hidden = e.type !== "waiting_for_operator";
    // The turn is done when the capture goes on; a cancel or failure stops it instead.
    if (waiting && e.type !== "waiting_for_operator" && e.type !== "finished") {
      const p = phases.get(waiting);
      endPhase(p, (performance.now() - p.since) / 1000);
      waiting = null;
    }
    if (e.type === "waiting_for_operator") {
      $("continue").dataset.view = e.view;
      waiting = WAITING(e.view);
      phaseRow(phases, waiting);
    }
    switch (e.type) {
      case "phase_started": {
        const p = phaseRow(phases, e.phase);
        p.bar.max = Math.max(e.total, 1);
        // The list's state moves with the capture's phases.
        refreshSessions().catch(showError);
        break;
      }
      case "progress": {
        const p = phaseRow(phases, e.phase);
        p.bar.max = Math.max(e.total, 1);
        p.bar.value = e.done;
        break;
      }
      case "phase_done": {
        endPhase(phaseRow(phases, e.phase), e.seconds);
        // A bracket's per-frame download bar has no end of its own: it goes with the
        // bracket's, as on the command line.
        const download = e.phase.replace(/: object bracket$/, ": download");
        if (download !== e.phase && phases.has(download)) {
          phases.get(download).div.remove();
          phases.delete(download);
        }
        break;
      }
      case "message":
      case "warning":
      case "waiting_for_operator":
        $("messages").append(el("li", e.text, { class: e.type }));
        break;
      case "finished":
        source.close();
        clearInterval(ticker);
        following = null;
        // A failed or cancelled capture ends phases that never finished: their bars stop
        // where they were, and download bars go (as on the command line).
        for (const [name, p] of phases) {
          if (p.div.classList.contains("done")) continue;
          p.div.classList.remove("running");
          if (name.endsWith(": download")) p.div.remove();
          else p.div.classList.add("stopped");
        }
        finished(e);
        break;
    }
  };
  source.onerror = () => {
    // The stream ends after `finished`; an error before that is a lost connection, which
    // EventSource retries on its own, unless the daemon refused the stream (503
    // `too_many_streams`: other pages follow captures), after which it never retries.
    if (!following) source.close();
    else if (source.readyState === EventSource.CLOSED) {
      showStatus(new Error("the daemon serves no more event streams now; reload this page to follow the capture"));
    }
  };
}

function finished(e) {
  $("cancel").hidden = true;
  $("continue").hidden = true;
  $("start").disabled = false;
  const out = $("outcome");
  out.replaceChildren();
  if (e.state === "done" && e.result) {
    const r = e.result;
    const fit = r.fit_error === null ? "not a number" : r.fit_error.toFixed(4);
    // The verdict first, as the command line's summary gives it: the fit is one of the
    // numbers it weighs, and a good fit can be an unsteady or flagged estimate.
    if (r.verdict_text) {
      out.append(el("p", `Verdict: ${r.verdict_text}`, { class: `verdict ${r.verdict}` }));
    }
    out.append(
      `Done: model ${r.model}` +
        (r.anisotropic_lobe ? ", relit with the anisotropic lobe it chose" : "") +
        `, fit to the photo ${fit} (${r.fit_verdict})` +
        (r.relight_error != null ? `, relit error ${r.relight_error.toFixed(4)}` : "") +
        (r.export_relight_error != null
          ? `; material.gltf relights ${r.export_relight_error.toFixed(3)} from the estimate (${r.export_verdict})`
          : "") +
        (r.mtlx_relight_error != null
          ? `, material.mtlx (OpenPBR) ${r.mtlx_relight_error.toFixed(3)} (${r.mtlx_verdict})`
          : "") +
        ". ",
      resultLinks(e.session)
    );
    // A part of two materials: each estimated on its own, with its own results.
    if ((r.materials || []).length > 0) {
      const p = el("p", `${r.materials.length} materials, each estimated on its own pixels (the fit and exports above are of one BRDF for the whole part, the verdict is theirs): `);
      const base = `/api/v1/sessions/${encodeURIComponent(e.session)}/result`;
      for (const m of r.materials) {
        const fit = m.fit_error === null ? "not a number" : m.fit_error.toFixed(4);
        p.append(
          `${m.folder}, ${Math.round(100 * m.share)}% of the pixels, fit ${fit} (${m.fit_verdict}): `,
          el("a", "report", { href: `${base}/${m.folder}/report.html`, target: "_blank" }),
          "; "
        );
      }
      p.append(el("a", "the split", { href: `${base}/materials.png`, target: "_blank" }));
      out.append(p);
    }
    // A broken assumption makes the figures optimistic: said under them, where it is read.
    for (const f of r.flags || []) {
      const p = document.createElement("p");
      p.className = "flag";
      p.textContent = `Flagged: ${f.text}`;
      out.append(p);
    }
  } else if (e.state === "done") {
    out.append("Done; the result could not be read back. ", resultLinks(e.session));
  } else if (e.cancelled) {
    out.className = "failed";
    out.textContent = `Cancelled. What was captured is kept: Resume, in the list below, continues it.`;
  } else {
    out.className = "failed";
    const next = NEXT_STEP[e.code];
    out.textContent =
      `${e.state}: ${e.error || "no reason given"}` + (next ? ` ${next}` : "");
  }
  refreshAll();
}

// What the operator can do about a failure, by its code (the finished event's `code`, the
// API's FailureCode). What was captured is kept whatever the cause.
const NEXT_STEP = {
  device_busy: "Another program holds the device: close it, then Resume below.",
  device_permission: "This user may not open the device: see the udev rules in docs/devices.md, then Resume below.",
  device_missing: "Check that the device is plugged in, switched on and reachable, then Resume below.",
  device_lost: "The device went away: reconnect it, then Resume below.",
  device_timeout: "The device did not answer in time: check it, then Resume below.",
  disk_full: "The disk is full: free space, then Resume below.",
};

async function start(event) {
  event.preventDefault();
  const form = new FormData($("capture"));
  const plan = { material: form.get("material") };
  if (!$("size-field").hidden) plan.size = Number(form.get("size"));
  clearError();
  const started = await post("/sessions", plan);
  follow(started.id);
  refreshAll();
}

async function resume(id) {
  clearError();
  await post(`/sessions/${encodeURIComponent(id)}/resume`);
  follow(id);
}

// Acknowledged at once, before the daemon answers: the capture stops at its next step (a
// camera mid-download finishes the file first), and the button must not look ignored.
async function cancel() {
  if (!following) return;
  const button = $("cancel");
  button.disabled = true;
  button.textContent = "Cancelling…";
  $("messages").append(
    el("li", "Cancel asked: the capture stops at its next step; what was captured is kept.", {
      class: "warning",
    })
  );
  try {
    await post(`/sessions/${encodeURIComponent(following.id)}/cancel`);
  } catch (e) {
    button.disabled = false;
    button.textContent = "Cancel it";
    throw e;
  }
}

// Says the object has been turned by hand, as the capture asked.
async function proceed() {
  $("continue").hidden = true;
  const view = Number($("continue").dataset.view);
  if (following) await post(`/sessions/${encodeURIComponent(following.id)}/continue`, { view });
}

async function refreshAll() {
  try {
    await Promise.all([refreshHealth(), refreshDevices(), refreshSessions()]);
  } catch (e) {
    showError(e);
  }
}

async function main() {
  $("capture").addEventListener("submit", (e) => start(e).catch(showError));
  $("cancel").addEventListener("click", () => cancel().catch(showError));
  $("continue").addEventListener("click", () => proceed().catch(showError));
  try {
    const health = await refreshHealth();
    $("app").hidden = false;
    await Promise.all([loadMaterials(), refreshDevices(), refreshSessions()]);
    if (health.busy) follow(health.busy);
  } catch (e) {
    showError(e);
    return;
  }
  setInterval(() => {
    refreshHealth().catch(showStatus);
    refreshDevices().catch(showStatus);
    refreshSessions().catch(showStatus);
  }, 5000);
}

main();
