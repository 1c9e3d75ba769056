// reachgrasp dashboard script: plain JavaScript, no dependencies, no build step.
// 1. Action forms post JSON to the API; problem+json field errors (JSONPath) are shown next to
//    the input whose data-path matches, anything else at the form's foot.
// 2. Job progress bars follow GET /v1/jobs/{id}/events (Server-Sent Events).
// 3. Figure view sliders re-request the SVG with azimuth/elevation (and other) parameters.
"use strict";

function setPath(obj, dotted, value) {
  const keys = dotted.split(".");
  let cur = obj;
  keys.forEach((k, i) => {
    const last = i === keys.length - 1;
    const nextIsIndex = !last && /^\d+$/.test(keys[i + 1]);
    const key = /^\d+$/.test(k) ? Number(k) : k;
    if (last) {
      cur[key] = value;
    } else {
      if (cur[key] === undefined) cur[key] = nextIsIndex ? [] : {};
      cur = cur[key];
    }
  });
}

// A field's value as JSON, or undefined when left empty (the API's default applies).
function fieldValue(el) {
  const type = el.dataset.type || "text";
  if (type === "bool") return el.checked;
  const raw = el.value.trim();
  if (raw === "") return undefined;
  if (type === "int" || type === "float") {
    const n = Number(raw);
    // Sent as typed even when not a number, so the server names the bad field.
    return Number.isFinite(n) ? n : raw;
  }
  if (type === "json") {
    // A choice between structured values (e.g. a plan's start: "current" or a configuration).
    try { return JSON.parse(raw); } catch (e) { return raw; }
  }
  if (type === "list") {
    return raw.split(/[\s,]+/).filter((s) => s !== "");
  }
  if (type === "vec") {
    return raw.split(/[\s,]+/).filter((s) => s !== "").map((s) => {
      const n = Number(s);
      return Number.isFinite(n) ? n : s;
    });
  }
  return raw;
}

function clearErrors(form) {
  form.querySelectorAll(".field-error").forEach((e) => { e.textContent = ""; });
  form.querySelectorAll(".field.invalid").forEach((e) => e.classList.remove("invalid"));
}

function showProblem(form, problem) {
  const unplaced = [];
  (problem.errors || []).forEach((err) => {
    // The exact field, else the field of the array it indexes into, else the first field
    // below the reported object (e.g. `$.demonstrations` -> `$.demonstrations.job_id`), else
    // the field holding the reported part (`$.start.positions[1]` -> `$.start`).
    const fields = Array.from(form.querySelectorAll("[data-path]"));
    const holds = (f) => err.path.startsWith(`${f.dataset.path}.`)
      || err.path.startsWith(`${f.dataset.path}[`);
    const input = fields.find((f) => f.dataset.path === err.path)
      || fields.find((f) => f.dataset.path === err.path.replace(/\[\d+\]$/, ""))
      || fields.find((f) => f.dataset.path.startsWith(`${err.path}.`)
        || f.dataset.path.startsWith(`${err.path}[`))
      || fields.filter(holds).sort((a, b) => b.dataset.path.length - a.dataset.path.length)[0];
    if (input) {
      const field = input.closest(".field");
      field.classList.add("invalid");
      const slot = field.querySelector(".field-error");
      slot.textContent = slot.textContent ? `${slot.textContent}; ${err.message}` : err.message;
    } else {
      unplaced.push(`${err.path}: ${err.message}`);
    }
  });
  const foot = form.querySelector(".form-error");
  if (unplaced.length > 0 || (problem.errors || []).length === 0) {
    foot.textContent = [problem.detail || problem.title || "request failed"].concat(unplaced).join(" — ");
  }
}

// The dashboard page of an API location (/v1/grasps/ID -> /ui/grasps/ID).
function uiHref(location) {
  return location.startsWith("/v1/") ? "/ui/" + location.slice(4) : location;
}

function resultHref(job) {
  const r = job.result;
  if (!r) return null;
  if (r.resource === "demonstrations") return `/ui/demonstrations?job_id=${job.id}`;
  if (r.resource.includes("/")) return r.href;
  return `/ui/${r.resource}/${r.id}`;
}

function renderJob(box, job) {
  const pct = Math.round(Math.max(0, Math.min(1, job.progress.fraction)) * 100);
  box.dataset.status = job.status;
  box.querySelector("progress").value = pct;
  const msg = job.progress.message ? ` — ${job.progress.message}` : "";
  const err = job.error ? ` — ${job.error.message}` : "";
  box.querySelector(".job-text").textContent = `${job.status} ${pct}%${msg}${err}`;
  const href = resultHref(job);
  const slot = box.querySelector(".job-result");
  if (href && !slot.querySelector("a")) {
    const a = document.createElement("a");
    a.href = href;
    a.textContent = "open result";
    slot.appendChild(a);
  }
}

const FINAL = ["succeeded", "failed", "cancelled"];

function followJob(box) {
  if (box.dataset.following || FINAL.includes(box.dataset.status)) return;
  box.dataset.following = "1";
  const source = new EventSource(`/v1/jobs/${box.dataset.job}/events`);
  const onEvent = (ev) => { renderJob(box, JSON.parse(ev.data)); };
  source.addEventListener("progress", onEvent);
  source.addEventListener("final", (ev) => { onEvent(ev); source.close(); });
  source.onerror = () => {
    // The stream ends after the final event; on a real failure fall back to one poll.
    source.close();
    if (!FINAL.includes(box.dataset.status)) {
      fetch(`/v1/jobs/${box.dataset.job}`).then((r) => r.json()).then((j) => renderJob(box, j))
        .catch(() => {});
    }
  };
}

// Executions on bridge workers: GET /v1/executions/{id}/events carries the execution with its
// latest feedback (progress 0..1, tracking error).
const EXEC_FINAL = ["succeeded", "failed", "aborted", "cancelled", "interrupted"];

function renderExecution(box, ex) {
  const fb = ex.last_feedback;
  const frac = ex.state === "succeeded" ? 1 : (fb ? fb.progress : 0);
  const pct = Math.round(Math.max(0, Math.min(1, frac)) * 100);
  box.dataset.status = ex.state;
  box.querySelector("progress").value = pct;
  const err = fb ? `, tracking error ${fb.tracking_error.toFixed(4)}` : "";
  const why = ex.reason ? ` — ${ex.reason}` : "";
  box.querySelector(".job-text").textContent = `${ex.state} ${pct}%${err}${why}`;
  if (EXEC_FINAL.includes(ex.state)) {
    const fig = document.querySelector("figure.plot[data-execution]");
    if (fig) fig.querySelector("img").src = `${fig.dataset.src}?t=${Date.now()}`;
  }
}

function followExecution(box) {
  if (box.dataset.following || EXEC_FINAL.includes(box.dataset.status)) return;
  box.dataset.following = "1";
  const source = new EventSource(`/v1/executions/${box.dataset.execution}/events`);
  const onEvent = (ev) => { renderExecution(box, JSON.parse(ev.data)); };
  source.addEventListener("progress", onEvent);
  source.addEventListener("final", (ev) => { onEvent(ev); source.close(); });
  source.onerror = () => { source.close(); };
}

function executionBox(ex) {
  const box = document.createElement("div");
  box.className = "job-status exec-status";
  box.dataset.execution = ex.id;
  box.dataset.status = ex.state;
  box.innerHTML = '<progress max="100" value="0"></progress> <span class="job-text"></span> '
    + `<a href="/ui/executions/${ex.id}">execution</a>`;
  renderExecution(box, ex);
  return box;
}

function jobBox(job) {
  const box = document.createElement("div");
  box.className = "job-status";
  box.dataset.job = job.id;
  box.dataset.status = job.status;
  box.innerHTML = '<progress max="100" value="0"></progress> <span class="job-text"></span> '
    + `<a href="/ui/jobs/${job.id}">job</a> <span class="job-result"></span>`;
  renderJob(box, job);
  return box;
}

async function submitForm(ev) {
  ev.preventDefault();
  const form = ev.target;
  clearErrors(form);
  const body = {};
  form.querySelectorAll("[name]").forEach((el) => {
    const v = fieldValue(el);
    if (v !== undefined) setPath(body, el.name, v);
  });
  const button = form.querySelector("button[type=submit]");
  const result = form.querySelector(".form-result");
  button.disabled = true;
  try {
    const res = await fetch(form.dataset.endpoint, {
      method: form.dataset.method || "POST",
      headers: { "content-type": "application/json", accept: "application/json" },
      body: JSON.stringify(body),
    });
    const type = res.headers.get("content-type") || "";
    const data = type.includes("json") ? await res.json() : { detail: await res.text() };
    if (!res.ok) {
      showProblem(form, data);
    } else if (res.status === 202 && data.id && data.state !== undefined) {
      const box = executionBox(data);
      result.prepend(box);
      followExecution(box);
    } else if (res.status === 202 && data.id) {
      const box = jobBox(data);
      result.prepend(box);
      followJob(box);
    } else if (res.headers.get("location")) {
      window.location.href = uiHref(res.headers.get("location"));
    } else {
      result.textContent = "done";
    }
  } catch (e) {
    form.querySelector(".form-error").textContent = `The service did not answer: ${e}`;
  } finally {
    button.disabled = false;
  }
}

function setupFigure(fig) {
  const img = fig.querySelector("img");
  const slot = fig.querySelector(".plot-error");
  let timer = null;
  const refresh = () => {
    const u = new URL(fig.dataset.src, window.location.href);
    fig.querySelectorAll(".controls [name]").forEach((el) => {
      if (el.value !== "") u.searchParams.set(el.name, el.value);
      else u.searchParams.delete(el.name);
    });
    const url = u.pathname + u.search;
    // Fetch first so a 4xx problem is shown instead of a broken image.
    fetch(url).then(async (res) => {
      if (res.ok) {
        slot.textContent = "";
        img.src = url;
      } else {
        const p = await res.json().catch(() => ({}));
        slot.textContent = p.detail || `HTTP ${res.status}`;
      }
    });
  };
  fig.querySelectorAll(".controls [name]").forEach((el) => {
    el.addEventListener(el.type === "range" ? "input" : "change", () => {
      clearTimeout(timer);
      timer = setTimeout(refresh, 120);
    });
  });
}

document.addEventListener("DOMContentLoaded", () => {
  document.querySelectorAll("form.api-form").forEach((f) => f.addEventListener("submit", submitForm));
  document.querySelectorAll(".job-status[data-job]").forEach(followJob);
  document.querySelectorAll(".exec-status[data-execution]").forEach(followExecution);
  document.querySelectorAll("figure.plot").forEach(setupFigure);
});
