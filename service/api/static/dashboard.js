// mocap lab dashboard: reads the JSON API (/v1) with the lab's key and fills the server's page.
// The key lives in this tab's sessionStorage and travels only in the Authorization header.
// Everything is written with textContent / setAttribute, never innerHTML: filenames, model
// names and error messages come from users.
"use strict";

(() => {
  const API = document.body.dataset.api;
  const KEY = "mocap.key";
  const TERMINAL = new Set(["succeeded", "failed", "canceled"]);
  const POLL_MS = 1000;   // each unfinished job: GET /v1/jobs/{id} (one row read on the server)
  const LIST_MS = 5000;   // the listings: new jobs, batches, uploads
  const PAGE = 50;
  const RESULTS = ["angles.csv", "histograms.xml", "report.json", "archive.zip"];
  // Artifacts a job has when its options asked (GET /v1/jobs/{id}/artifacts lists them): these
  // are shown as images; every artifact is offered for download. The error-over-time plot is
  // drawn here from angles.csv in any case.
  const PLOTS = ["plots/angles.png", "plots/histograms.png"];
  const CONTACT_SHEET = "overlay/contact_sheet.png";
  const SVG = "http://www.w3.org/2000/svg";

  const $ = (id) => document.getElementById(id);
  const state = { jobs: new Map(), batches: new Map(), pages: {}, selected: null, shown: null,
                  timers: [], generation: 0, images: [] };

  class Unauthorized extends Error {}

  // ---- HTTP ------------------------------------------------------------------------------------
  async function api(path, as = "json") {
    const response = await fetch(API + path, {
      headers: { Authorization: `Bearer ${sessionStorage.getItem(KEY)}` }, cache: "no-store" });
    if (response.status === 401) {
      signOut("The key was not accepted: sign in again.");
      throw new Unauthorized();
    }
    if (!response.ok) {
      let detail = response.statusText;
      try { detail = (await response.json()).detail; } catch { /* not the API's JSON error */ }
      const error = new Error(detail);
      error.status = response.status;
      throw error;
    }
    return as === "json" ? response.json() : as === "text" ? response.text() : response.blob();
  }

  async function pages(path, count) {
    // The first `count` pages of a listing (newest first); `more`: there are older rows.
    let items = [], cursor = null;
    for (let i = 0; i < count; i++) {
      const page = await api(`${path}?limit=${PAGE}${cursor ? `&cursor=${cursor}` : ""}`);
      items = items.concat(page.items);
      cursor = page.next_cursor;
      if (cursor === null) break;
    }
    return { items, more: cursor !== null };
  }

  // ---- DOM helpers -----------------------------------------------------------------------------
  function el(tag, attrs = {}, ...children) {
    const node = document.createElement(tag);
    for (const [name, value] of Object.entries(attrs)) {
      if (name === "text") node.textContent = value;
      else if (name === "class") node.className = value;
      else node.setAttribute(name, value);
    }
    node.append(...children);
    return node;
  }
  const td = (text, cls) => el("td", cls ? { class: cls, text: String(text) } : { text: String(text) });
  const numeric = (value) => td(value, "num");

  function when(iso) {
    if (!iso) return el("td", { text: "–" });
    return el("td", {}, el("time", { datetime: iso, text: local(iso) }));
  }

  function local(iso) {
    // "2026-11-23 14:05:09" in the browser's time zone: sortable, and the same in every locale.
    const d = new Date(iso), two = (n) => String(n).padStart(2, "0");
    return `${d.getFullYear()}-${two(d.getMonth() + 1)}-${two(d.getDate())} `
      + `${two(d.getHours())}:${two(d.getMinutes())}:${two(d.getSeconds())}`;
  }

  function statusCell(status) {
    return el("td", {}, el("span", { class: `status status-${status}`, text: status }));
  }

  function fill(tableId, rows, emptyId) {
    $(tableId).tBodies[0].replaceChildren(...rows);
    if (emptyId) $(emptyId).hidden = rows.length > 0;
  }

  function announce(text) { $("status-line").textContent = text; }

  // ---- sign in / out ---------------------------------------------------------------------------
  async function signIn(event) {
    event.preventDefault();
    const input = $("key");
    const key = input.value.trim();
    input.value = "";
    if (!key) return;
    sessionStorage.setItem(KEY, key);
    start();
  }

  async function start() {
    $("sign-in-problem").textContent = "";
    const generation = ++state.generation;
    try {
      await refreshLists();
    } catch (error) {
      if (!(error instanceof Unauthorized)) $("sign-in-problem").textContent = `The service: ${error.message}`;
      return;
    }
    if (generation !== state.generation) return;
    $("sign-in").hidden = true;
    $("lab").hidden = false;
    $("sign-out").hidden = false;
    route();
    loop(refreshLists, LIST_MS, generation);
    loop(pollRunning, POLL_MS, generation);
  }

  function signOut(message = "") {
    sessionStorage.removeItem(KEY);
    state.generation++;
    state.timers.forEach(clearTimeout);
    state.timers = [];
    state.jobs.clear();
    state.batches.clear();
    state.pages = {};
    state.selected = state.shown = null;
    for (const id of ["jobs", "batches", "models", "rigs", "videos", "job-counts"]) fill(id, []);
    $("job-plot-body").replaceChildren();
    $("lab").hidden = true;
    $("sign-out").hidden = true;
    $("sign-in").hidden = false;
    $("sign-in-problem").textContent = message;
    $("key").focus();
  }

  function loop(step, ms, generation) {
    // Run `step` every `ms` after the last run ended, until the user signs out.
    const next = () => {
      if (generation !== state.generation) return;
      state.timers.push(setTimeout(async () => {
        try { await step(); } catch (error) {
          if (!(error instanceof Unauthorized)) announce(`Could not update: ${error.message}`);
        }
        next();
      }, ms));
    };
    next();
  }

  // ---- listings --------------------------------------------------------------------------------
  const LISTINGS = {
    jobs: { path: "/jobs", row: jobRow, empty: "jobs-empty" },
    models: { path: "/models", row: modelRow },
    rigs: { path: "/rigs", row: rigRow },
    videos: { path: "/videos", row: videoRow },
  };

  async function refreshLists() {
    const loaded = await Promise.all(Object.entries(LISTINGS).map(async ([name, listing]) =>
      [name, await pages(listing.path, state.pages[name] ?? 1)]));
    for (const [name, { items, more }] of loaded) {
      if (name === "jobs") items.forEach(noteJob);
      fill(name, items.map(LISTINGS[name].row), LISTINGS[name].empty);
      moreButton(name, more);
    }
    await refreshBatches();
  }

  function moreButton(name, more) {
    const id = `${name}-more`;
    let button = $(id);
    if (!button) {
      button = el("button", { type: "button", id, text: `Show older ${name}` });
      button.addEventListener("click", async () => {
        state.pages[name] = (state.pages[name] ?? 1) + 1;
        await refreshLists();
      });
      $(name).after(button);
    }
    button.hidden = !more;
  }

  function noteJob(job) {
    const before = state.jobs.get(job.id);
    if (before && before.status !== job.status) announce(`Job ${job.id} ${job.status}.`);
    state.jobs.set(job.id, job);
  }

  function jobRow(job) {
    const p = job.progress;
    const trial = job.batch_id === null ? "–" : `batch ${job.batch_id}, trial ${job.trial}`;
    const row = el("tr", { id: `job-row-${job.id}`, "data-status": job.status },
      el("th", { scope: "row" }, el("a", { href: `#job-${job.id}`, text: `Job ${job.id}` })),
      td(trial), statusCell(job.status),
      el("td", {}, progressBar(job, `Job ${job.id}: images fitted`), " ",
         el("span", { class: "progress-text", text: progressText(job) })),
      numeric(p.images_over_threshold), when(job.created_at), when(job.finished_at));
    if (job.id === state.selected) row.classList.add("selected");
    return row;
  }

  function progressBar(job, label) {
    const p = job.progress;
    return el("progress", { max: String(Math.max(p.images_total, 1)), value: String(p.images_done),
                            "aria-label": label });
  }

  function progressText(job) {
    const p = job.progress;
    if (!p.images_total) return job.status === "queued" ? "waiting to be planned" : "";
    let text = `${p.images_done} / ${p.images_total} images`;
    if (p.reanalyses_pending) text += `, ${p.reanalyses_pending} re-analyses pending`;
    return text;
  }

  function modelRow(model) {
    return el("tr", {}, el("th", { scope: "row", text: `Model ${model.id}` }), td(model.name),
      td(model.dofs.join(", ")), numeric(model.histogram_versions), when(model.created_at));
  }

  function rigRow(rig) {
    return el("tr", {}, el("th", { scope: "row", text: `Rig ${rig.id}` }), td(rig.views.join(", ")),
      numeric(rig.videos), when(rig.created_at));
  }

  function videoRow(video) {
    return el("tr", {}, el("th", { scope: "row", text: `Video ${video.id}` }), td(video.filename),
      numeric(video.frames), numeric(video.fps), td(`${video.width} × ${video.height}`),
      numeric(video.size_bytes.toLocaleString()),
      el("td", {}, el("code", { title: video.sha256, text: `${video.sha256.slice(0, 12)}…` })),
      when(video.created_at));
  }

  // ---- batches: those of the listed jobs -------------------------------------------------------
  async function refreshBatches() {
    const ids = [...new Set([...state.jobs.values()].map((j) => j.batch_id).filter((b) => b !== null))];
    await Promise.all(ids.filter((id) => !TERMINAL.has(state.batches.get(id)?.status))
      .map(async (id) => state.batches.set(id, await api(`/batches/${id}`))));
    const rows = ids.sort((a, b) => b - a).map((id) => batchRow(state.batches.get(id)));
    fill("batches", rows, "batches-empty");
  }

  function batchRow(batch) {
    const statuses = Object.entries(batch.statuses).map(([s, n]) => `${n} ${s}`).join(", ");
    const download = batch.status === "succeeded"
      ? el("td", {}, downloadLink(`/batches/${batch.id}/archive.zip`, `batch-${batch.id}.zip`, "archive.zip"))
      : td("once every job has succeeded");
    return el("tr", { id: `batch-row-${batch.id}` }, el("th", { scope: "row", text: `Batch ${batch.id}` }),
      statusCell(batch.status), td(statuses),
      el("td", {}, progressBar(batch, `Batch ${batch.id}: images fitted`), " ",
         el("span", { text: progressText(batch) })), download);
  }

  // ---- live progress ---------------------------------------------------------------------------
  async function pollRunning() {
    const running = new Set([...state.jobs.values()].filter((j) => !TERMINAL.has(j.status)).map((j) => j.id));
    if (state.shown && !TERMINAL.has(state.shown.status)) running.add(state.shown.id);
    for (const id of running) {
      const job = await api(`/jobs/${id}`);
      if (state.jobs.has(id)) {
        noteJob(job);
        $(`job-row-${id}`)?.replaceWith(jobRow(job));
      }
      if (id === state.selected) await showJob(job);
    }
  }

  // ---- one job ---------------------------------------------------------------------------------
  function route() {
    const match = /^#job-(\d+)$/.exec(location.hash);
    const id = match ? Number(match[1]) : null;
    document.querySelectorAll("#jobs tr.selected").forEach((r) => r.classList.remove("selected"));
    state.selected = id;
    state.shown = null;
    $("job").hidden = id === null;
    if (id === null) return;
    $(`job-row-${id}`)?.classList.add("selected");
    $("job-heading").textContent = `Job ${id}`;
    $("job-problem").textContent = "";
    $("job-body").hidden = true;
    $("job-heading").focus();
    api(`/jobs/${id}`).then(showJob).catch((error) => {
      if (error instanceof Unauthorized || id !== state.selected) return;
      $("job-problem").textContent = error.status === 404
        ? `Job ${id} does not exist or belongs to another lab.` : `Job ${id}: ${error.message}`;
    });
  }

  async function showJob(job) {
    if (job.id !== state.selected) return;
    const first = state.shown === null;
    const finished = state.shown?.status !== "succeeded" && job.status === "succeeded";
    state.shown = job;
    $("job-body").hidden = false;
    $("job-heading").textContent = `Job ${job.id}: ${job.status}`;
    facts(job);
    $("job-progress").max = Math.max(job.progress.images_total, 1);
    $("job-progress").value = job.progress.images_done;
    $("job-progress-text").textContent = progressText(job);
    if (first || finished) await results(job);
    if (job.status !== "succeeded") counts([["fitted", job.progress.images_done],
      ["over the threshold so far", job.progress.images_over_threshold],
      ["re-analyses pending", job.progress.reanalyses_pending]]);
  }

  function facts(job) {
    const o = job.options;
    const items = [
      ["Status", job.status], ["Model", `model ${job.model_id}`], ["Rig", `rig ${job.rig_id}`],
      ["Batch", job.batch_id === null ? "–" : `batch ${job.batch_id}, trial ${job.trial}`],
      ["Error threshold", `${o.error_threshold_px} px per marker`],
      ["Marker diameter", o.marker_diameter_px === "auto" ? "estimated from the video" : `${o.marker_diameter_px} px`],
      ["Seed, iterations", `${o.seed}, ${o.iterations}`],
      ["Submitted", local(job.created_at)], ["Finished", job.finished_at ? local(job.finished_at) : "–"],
    ];
    if (job.error) items.push(["Error", job.error]);
    $("job-facts").replaceChildren(...items.flatMap(([k, v]) => [el("dt", { text: k }), el("dd", { text: v })]));
  }

  function counts(rows) {
    fill("job-counts", rows.map(([name, n]) => el("tr", {}, el("th", { scope: "row", text: name }), numeric(n))));
  }

  async function results(job) {
    const downloads = $("job-downloads");
    const overlay = $("job-overlay");
    overlay.hidden = $("job-plots").hidden = $("job-advice").hidden = $("job-ambiguous").hidden = true;
    state.images.splice(0).forEach(URL.revokeObjectURL);  // the images of the job shown before
    if (job.status !== "succeeded") {
      downloads.replaceChildren(el("li", { text: "Results can be downloaded once the job has succeeded." }));
      $("job-plot-body").replaceChildren(el("p", { class: "empty", text: "Drawn once the job has succeeded." }));
      $("job-plot-caption").textContent = "";
      return;
    }
    const [report, angles, extra] = await Promise.all([api(`/jobs/${job.id}/report.json`),
      api(`/jobs/${job.id}/angles.csv`, "text"), artifacts(job)]);
    if (job.id !== state.selected) return;
    downloads.replaceChildren(
      ...RESULTS.map((name) => el("li", {}, downloadLink(`/jobs/${job.id}/${name}`, `job-${job.id}-${name}`, name))),
      ...extra.map((name) => el("li", {}, downloadLink(`/jobs/${job.id}/artifacts/${name}`,
                                                       `job-${job.id}-${name.replaceAll("/", "-")}`, name))));
    counts([...Object.entries(report.status), ["re-analysed", report.reanalysed],
      ["ambiguous", report.ambiguous]]);
    // report.json's ambiguous_dofs: which DOF each ambiguous image's alternative differs most in
    const dofs = Object.entries(report.ambiguous_dofs).sort((a, b) => b[1] - a[1]);
    $("job-ambiguous").textContent = "Ambiguous images by the DOF their alternative differs most in: "
      + dofs.map(([dof, n]) => `${dof} ${n}`).join(", ") + ".";
    $("job-ambiguous").hidden = dofs.length === 0;
    // report.json's advice: most images over the threshold, or else ambiguous, and what to do
    $("job-advice").replaceChildren(...report.advice.map((line) => el("li", { text: line })));
    $("job-advice").hidden = report.advice.length === 0;
    const plot = errorPlot(parseAngles(angles), job.options.error_threshold_px);
    $("job-plot-body").replaceChildren(plot.svg);
    $("job-plot-caption").textContent = plot.summary;
    const plots = PLOTS.filter((p) => extra.includes(p));
    $("job-plots").hidden = plots.length === 0;
    $("job-plots-body").replaceChildren();
    for (const name of plots) {
      const what = name.includes("histograms") ? "Joint-angle histograms (Eq. 4), at the start and after the job"
        : "Each degree of freedom over time: histogram range shaded, over-threshold, ambiguous and re-analysed images marked";
      $("job-plots-body").append(el("figure", {}, el("div", { class: "plot-window" }, el("img", {
        src: await image(job, name), alt: what, "data-artifact": name })),
      el("figcaption", { text: `${what} (${name}).` })));
    }
    if (extra.includes(CONTACT_SHEET)) {
      $("job-overlay-image").src = await image(job, CONTACT_SHEET);
      $("job-overlay-image").alt = `Worst and ambiguous images of job ${job.id} with the fitted model drawn over them`;
      overlay.hidden = false;
    }
  }

  async function artifacts(job) {
    // Names of the job's artifacts; none where the service has no artifacts (404) or the job none.
    try {
      return await api(`/jobs/${job.id}/artifacts`);
    } catch (error) {
      if (error.status === 404) return [];
      throw error;
    }
  }

  async function image(job, name) {
    const url = URL.createObjectURL(await api(`/jobs/${job.id}/artifacts/${name}`, "blob"));
    state.images.push(url);
    return url;
  }

  function downloadLink(path, filename, label) {
    // A real link (its URL is the API's), fetched with the key on click and saved as a file.
    const link = el("a", { href: API + path, download: filename, text: label });
    link.addEventListener("click", async (event) => {
      event.preventDefault();
      try {
        const url = URL.createObjectURL(await api(path, "blob"));
        const save = el("a", { href: url, download: filename });
        document.body.append(save);
        save.click();
        save.remove();
        setTimeout(() => URL.revokeObjectURL(url), 30000);
      } catch (error) {
        if (!(error instanceof Unauthorized)) announce(`Could not download ${label}: ${error.message}`);
      }
    });
    return link;
  }

  // ---- error over time, from angles.csv (FORMATS §3) -------------------------------------------
  function parseAngles(text) {
    const lines = text.split("\n").filter((line) => line.length);
    const header = lines[0].split(",");
    const column = (name) => header.indexOf(name);
    const perMarker = column("error_per_marker_px") >= 0;
    const [t, e, s, a] = [column("time_s"), column(perMarker ? "error_per_marker_px" : "error_px"),
                          column("status"), column("alternative_deg")];
    const rows = lines.slice(1).map((line) => {
      const cells = line.split(",");
      return { time: Number(cells[t]), error: cells[e] === "" ? NaN : Number(cells[e]),
               status: cells[s], ambiguous: a >= 0 && cells[a] !== "" };
    });
    return { rows, perMarker };
  }

  function svg(tag, attrs = {}, text) {
    const node = document.createElementNS(SVG, tag);
    for (const [name, value] of Object.entries(attrs)) node.setAttribute(name, String(value));
    if (text !== undefined) node.textContent = text;
    return node;
  }

  function niceMax(value) {
    const step = 10 ** Math.floor(Math.log10(value));
    return [1, 2, 2.5, 5, 10].map((m) => m * step).find((m) => m >= value);
  }

  function errorPlot({ rows, perMarker }, threshold) {
    // Error per image over time: the largest error in each pixel column (so a million images
    // still draw as ~650 points), the threshold, over-threshold images as dots, and two strips
    // of ticks below: ambiguous images and images without detections.
    const W = 760, H = 300, left = 96, right = 12, top = 14, bottom = 78;
    const plotW = W - left - right, plotH = H - top - bottom;
    const fitted = rows.filter((r) => Number.isFinite(r.error));
    const t0 = rows.length ? rows[0].time : 0, t1 = rows.length ? rows[rows.length - 1].time : 1;
    const span = t1 > t0 ? t1 - t0 : 1;
    // The range of the errors (not of the threshold, which would flatten well-fitted images).
    const yMax = niceMax(fitted.reduce((m, r) => Math.max(m, r.error), 1e-3));
    const x = (time) => left + ((time - t0) / span) * plotW;
    const y = (error) => top + plotH - (Math.min(error, yMax) / yMax) * plotH;
    const columns = new Map();
    for (const r of fitted) {
      const c = Math.round(x(r.time));
      if (!columns.has(c) || columns.get(c) < r.error) columns.set(c, r.error);
    }
    const over = rows.filter((r) => r.status === "over_threshold" && Number.isFinite(r.error));
    const ambiguous = rows.filter((r) => r.ambiguous);
    const none = rows.filter((r) => r.status === "no_detections");
    const sorted = fitted.map((r) => r.error).sort((p, q) => p - q);
    const median = sorted.length ? sorted[Math.floor(sorted.length / 2)] : NaN;
    const unit = perMarker ? "px per marker" : "px (Eq. 5 total)";
    const summary = `${rows.length} images over ${span.toFixed(2)} s; error median ${median.toFixed(2)}, `
      + `max ${(sorted.at(-1) ?? NaN).toFixed(2)} ${unit}; ${over.length} over the threshold of ${threshold} px; `
      + `${ambiguous.length} ambiguous; ${none.length} without detections.`;

    const root = svg("svg", { viewBox: `0 0 ${W} ${H}`, role: "img", "aria-labelledby": "plot-title plot-desc",
                              id: "error-plot" });
    root.append(svg("title", { id: "plot-title" }, "Error over time"), svg("desc", { id: "plot-desc" }, summary));
    const divisions = yMax / 10 ** Math.floor(Math.log10(yMax)) === 2 ? 4 : 5;
    const decimals = Math.max(0, 1 - Math.floor(Math.log10(yMax / divisions)));
    for (let i = 0; i <= divisions; i++) {
      const value = (yMax * i) / divisions;
      root.append(svg("line", { class: "plot-grid", x1: left, x2: W - right, y1: y(value), y2: y(value) }),
        svg("text", { class: "plot-text", x: left - 6, y: y(value) + 4, "text-anchor": "end" }, `${+value.toFixed(decimals)}`));
    }
    root.append(svg("line", { class: "plot-axis", x1: left, x2: left, y1: top, y2: top + plotH }),
      svg("line", { class: "plot-axis", x1: left, x2: W - right, y1: top + plotH, y2: top + plotH }));
    for (const frac of [0, 0.5, 1]) {
      root.append(svg("text", { class: "plot-text", x: left + frac * plotW, y: top + plotH + 16,
        "text-anchor": ["start", "middle", "end"][frac * 2] }, `${(t0 + frac * span).toFixed(2)} s`));
    }
    root.append(svg("text", { class: "plot-text", x: 16, y: top + plotH / 2, "text-anchor": "middle",
      transform: `rotate(-90 16 ${top + plotH / 2})` }, `error (${perMarker ? "px per marker" : "px"})`));
    if (threshold <= yMax) {
      root.append(svg("line", { class: "plot-threshold", x1: left, x2: W - right, y1: y(threshold), y2: y(threshold) }));
    } else {
      root.append(svg("text", { class: "plot-text", x: W - right, y: top + 12, "text-anchor": "end" },
                      `threshold ${threshold} px: above this range`));
    }
    const points = [...columns.entries()].sort((p, q) => p[0] - q[0]).map(([c, e]) => `${c},${y(e).toFixed(1)}`);
    root.append(svg("polyline", { class: "plot-line", points: points.join(" ") }));
    for (const r of over.slice(0, 2000)) root.append(svg("circle", { class: "plot-over", cx: x(r.time), cy: y(r.error), r: 3 }));
    const strip = (items, row, label, cls) => {
      const y0 = top + plotH + 26 + row * 18;
      root.append(svg("text", { class: "plot-text", x: left - 6, y: y0 + 10, "text-anchor": "end" }, label));
      for (const r of items.slice(0, 5000)) {
        root.append(svg("line", { class: cls, x1: x(r.time), x2: x(r.time), y1: y0, y2: y0 + 12 }));
      }
    };
    strip(ambiguous, 0, "ambiguous", "plot-ambiguous");
    strip(none, 1, "no detections", "plot-none");
    return { svg: root, summary };
  }

  // ---- start -----------------------------------------------------------------------------------
  $("sign-in-form").addEventListener("submit", signIn);
  $("sign-out").addEventListener("click", () => signOut());
  window.addEventListener("hashchange", route);
  if (sessionStorage.getItem(KEY)) start();
})();
