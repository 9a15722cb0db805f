// facestats population page: filters -> /api/query, /api/pca, /api/scatter -> tables and SVG plots.
// No external libraries: every plot is SVG drawn here.
"use strict";

const SVG = "http://www.w3.org/2000/svg";
const CH_COLOURS = { R: "#c0392b", G: "#27ae60", B: "#2c6fbb" };

function fmt(x) {
  return x === null || x === undefined ? "–" : Number(x).toPrecision(4);
}

function el(tag, attrs, text) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
}

function svgEl(tag, attrs) {
  const e = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
  return e;
}

function valueCell(key, x) {
  const td = el("td", { "data-key": key }, fmt(x));
  if (x !== null && x !== undefined) td.setAttribute("data-value", String(x));
  return td;
}

function queryString() {
  const params = new URLSearchParams();
  for (const input of document.querySelectorAll("#filters select, #filters input")) {
    if (input.value.trim()) params.set(input.name, input.value.trim());
  }
  return params.toString();
}

// -- plots -------------------------------------------------------------------------------
function axes(svg, w, h, m, xr, yr, xl, yl) {
  const sx = (x) => m + ((x - xr[0]) / (xr[1] - xr[0] || 1)) * (w - 2 * m);
  const sy = (y) => h - m - ((y - yr[0]) / (yr[1] - yr[0] || 1)) * (h - 2 * m);
  svg.appendChild(svgEl("line", { x1: m, y1: h - m, x2: w - m, y2: h - m, stroke: "#444" }));
  svg.appendChild(svgEl("line", { x1: m, y1: m, x2: m, y2: h - m, stroke: "#444" }));
  for (const [x, y, t, a] of [[w / 2, h - 4, xl, "middle"], [4, 12, yl, "start"],
    [m, h - m + 12, fmt(xr[0]), "middle"], [w - m, h - m + 12, fmt(xr[1]), "middle"],
    [m - 2, h - m, fmt(yr[0]), "end"], [m - 2, m + 4, fmt(yr[1]), "end"]]) {
    const text = svgEl("text", { x: x, y: y, "font-size": 10, "text-anchor": a });
    text.textContent = t;
    svg.appendChild(text);
  }
  return [sx, sy];
}

function histogramPlot(values, ch) {
  const w = 280, h = 140, m = 28;
  const svg = svgEl("svg", { width: w, height: h, class: "histogram", "data-channel": ch });
  const ymax = Math.max(...values, 1e-12);
  const [sx, sy] = axes(svg, w, h, m, [0, 1], [0, ymax], "albedo " + ch, "fraction");
  values.forEach((v, i) => {
    if (v <= 0) return;
    svg.appendChild(svgEl("rect", { x: sx(i / values.length), y: sy(v), width: Math.max(sx(1 / values.length) - sx(0), 1),
      height: sy(0) - sy(v), fill: CH_COLOURS[ch] }));
  });
  return svg;
}

function barPlot(regions, param) {
  const w = 300, h = 150, m = 30;
  const svg = svgEl("svg", { width: w, height: h, class: "bars", "data-param": param });
  const stats = regions.map((r) => r[param]);
  const top = Math.max(...stats.map((s) => (s.mean || 0) + (s.std || 0)), 1e-12);
  const [sx, sy] = axes(svg, w, h, m, [0.5, regions.length + 0.5], [0, top], param + " by region", "");
  regions.forEach((r, i) => {
    const s = r[param];
    if (s.mean === null) return;
    const x = sx(i + 1) - 8;
    svg.appendChild(svgEl("rect", { x: x, y: sy(s.mean), width: 16, height: sy(0) - sy(s.mean), fill: "#a0522d" }));
    if (s.std !== null) {
      svg.appendChild(svgEl("line", { x1: x + 8, x2: x + 8, y1: sy(s.mean - s.std), y2: sy(s.mean + s.std), stroke: "#000" }));
    }
    const t = svgEl("text", { x: x + 8, y: h - m + 22, "font-size": 9, "text-anchor": "middle" });
    t.textContent = r.region;
    svg.appendChild(t);
  });
  return svg;
}

function ellipsePlot(doc) {
  const w = 420, h = 320, m = 36;
  const svg = svgEl("svg", { width: w, height: h, id: "pca-plot" });
  const xs = [], ys = [];
  for (const r of doc.regions) {
    const ext = Math.max(...r.half_axes);
    xs.push(r.mean[0] - ext, r.mean[0] + ext);
    ys.push(r.mean[1] - ext, r.mean[1] + ext);
  }
  const [sx, sy] = axes(svg, w, h, m, [Math.min(...xs), Math.max(...xs)], [Math.min(...ys), Math.max(...ys)], "ρs", "m");
  for (const r of doc.regions) {
    let d = "";
    for (let k = 0; k <= 48; k++) {
      const t = (2 * Math.PI * k) / 48;
      const a = r.half_axes[0] * Math.cos(t), b = r.half_axes[1] * Math.sin(t);
      const x = r.mean[0] + a * r.axis[0] - b * r.axis[1];
      const y = r.mean[1] + a * r.axis[1] + b * r.axis[0];
      d += (k ? "L" : "M") + sx(x).toFixed(1) + "," + sy(y).toFixed(1);
    }
    svg.appendChild(svgEl("path", { d: d, fill: "none", stroke: "hsl(" + r.region * 36 + ",60%,40%)", class: "ellipse" }));
    const t = svgEl("text", { x: sx(r.mean[0]), y: sy(r.mean[1]), "font-size": 10, "text-anchor": "middle" });
    t.textContent = r.region;
    svg.appendChild(t);
  }
  return svg;
}

function scatterPlot(points) {
  const w = 420, h = 320, m = 36;
  const svg = svgEl("svg", { width: w, height: h, id: "scatter-plot" });
  const xs = points.map((p) => p.sigma_s_prime), ys = points.map((p) => p.sigma_a);
  const [sx, sy] = axes(svg, w, h, m, [0, Math.max(...xs) * 1.05], [0, Math.max(...ys) * 1.05], "σ's (mm⁻¹)", "σa (mm⁻¹)");
  for (const p of points) {
    const r = 1.5 + p.age / 25;
    const shape = p.gender === "F"
      ? svgEl("rect", { x: sx(p.sigma_s_prime) - r, y: sy(p.sigma_a) - r, width: 2 * r, height: 2 * r,
        transform: "rotate(45 " + sx(p.sigma_s_prime) + " " + sy(p.sigma_a) + ")" })
      : svgEl("circle", { cx: sx(p.sigma_s_prime), cy: sy(p.sigma_a), r: r });
    shape.setAttribute("fill", CH_COLOURS[p.channel]);
    shape.setAttribute("fill-opacity", 0.25 + 0.12 * p.skin_type);
    shape.setAttribute("class", "point");
    svg.appendChild(shape);
  }
  return svg;
}

// -- tables ------------------------------------------------------------------------------
function fillTables(doc) {
  document.getElementById("summary").textContent =
    "store " + doc.store + ": " + doc.count + " of " + doc.n_store_subjects + " subjects match (" + doc.n_persons + " persons)";
  const bd = document.getElementById("breakdown");
  bd.replaceChildren();
  for (const [k, counts] of Object.entries(doc.breakdown)) {
    bd.appendChild(el("div", {}, k + ": " + Object.entries(counts).map(([a, b]) => a + " " + b).join(", ")));
  }
  const at = document.getElementById("albedo-table");
  at.replaceChildren(el("tr"));
  at.firstChild.append(el("th", {}, "albedo"), el("th", {}, "mean"), el("th", {}, "std"), el("th", {}, "n"));
  for (const [ch, s] of Object.entries(doc.albedo)) {
    const tr = el("tr");
    tr.append(el("th", {}, ch), valueCell("albedo." + ch + ".mean", s.mean), valueCell("albedo." + ch + ".std", s.std), el("td", {}, s.n));
    at.appendChild(tr);
  }
  const rt = document.getElementById("region-table");
  rt.replaceChildren();
  const head = el("tr");
  head.append(el("th", {}, "region"));
  // Between-subject spread (std of the subjects' region means) beside the within-subject uncertainty
  // (the fit's standard error of a subject's region mean, RMS over the subjects; absent without std maps).
  for (const p of ["ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent"]) {
    head.append(el("th", {}, p + " mean"), el("th", { title: "between subjects" }, p + " std"),
      el("th", { title: "fit standard error of a subject's region mean (within subject)" }, p + " se"));
  }
  rt.appendChild(head);
  for (const r of doc.regions) {
    const tr = el("tr");
    tr.append(el("th", {}, r.region + " " + r.name));
    for (const p of ["ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent"]) {
      tr.append(valueCell("regions." + r.region + "." + p + ".mean", r[p].mean), valueCell("regions." + r.region + "." + p + ".std", r[p].std),
        valueCell("regions." + r.region + "." + p + ".mean_se", r[p].mean_se));
    }
    rt.appendChild(tr);
  }
  const st = document.getElementById("scattering-table");
  st.replaceChildren();
  const sh = el("tr");
  sh.append(el("th", {}, "mm⁻¹"), el("th", {}, "R"), el("th", {}, "G"), el("th", {}, "B"));
  st.appendChild(sh);
  for (const [p, chans] of Object.entries(doc.scattering)) {
    const tr = el("tr");
    tr.append(el("th", {}, p));
    for (const ch of ["R", "G", "B"]) tr.append(valueCell("scattering." + p + "." + ch + ".mean", chans[ch].mean));
    st.appendChild(tr);
  }
  const subj = document.getElementById("subjects");
  subj.replaceChildren(...doc.subject_ids.map((id) => {
    const a = el("a", { href: "subject/" + encodeURIComponent(id), class: "subject-link" }, id);
    return a;
  }).flatMap((a) => [a, document.createTextNode(" ")]));
}

function drawPlots(doc) {
  const hist = document.getElementById("histograms");
  hist.replaceChildren();
  for (const ch of ["R", "G", "B"]) if (doc.albedo_histogram[ch]) hist.appendChild(histogramPlot(doc.albedo_histogram[ch], ch));
  const bars = document.getElementById("region-bars");
  bars.replaceChildren();
  if (doc.count) for (const p of ["ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent"]) bars.appendChild(barPlot(doc.regions, p));
}

// -- loading -----------------------------------------------------------------------------
let generation = 0;

async function getJSON(url) {
  const res = await fetch(url);
  const body = await res.json();
  if (!res.ok) throw new Error(body.error || res.statusText);
  return [res.status, body];
}

async function loadPca(qs, gen) {
  const box = document.getElementById("pca");
  try {
    const [status, doc] = await getJSON("api/pca?" + qs);
    if (gen !== generation) return;
    if (status === 202) {
      box.textContent = "reading the region samples of every subject…";
      setTimeout(() => loadPca(qs, gen), 1000);
      return;
    }
    box.replaceChildren(doc.status === "ok" ? ellipsePlot(doc) : el("p", {}, doc.error || "no samples"));
  } catch (e) {
    box.textContent = e.message;
  }
}

async function refresh() {
  const gen = ++generation;
  const qs = queryString();
  document.getElementById("dl-json").href = "api/query?" + qs;
  document.getElementById("dl-csv").href = "api/query.csv?" + qs;
  history.replaceState(null, "", "?" + qs);
  const err = document.getElementById("error");
  try {
    const [, doc] = await getJSON("api/query?" + qs);
    if (gen !== generation) return;
    err.hidden = true;
    fillTables(doc);
    drawPlots(doc);
    document.body.setAttribute("data-query", qs);
    document.body.setAttribute("data-count", doc.count);
    const [, sc] = await getJSON("api/scatter?" + qs);
    if (gen !== generation) return;
    document.getElementById("scatter").replaceChildren(sc.points.length ? scatterPlot(sc.points) : el("p", {}, "no points"));
    loadPca(qs, gen);
  } catch (e) {
    if (gen !== generation) return;
    err.textContent = e.message;
    err.hidden = false;
    document.body.setAttribute("data-query", qs);
    document.body.setAttribute("data-count", "error");
  }
}

window.addEventListener("DOMContentLoaded", () => {
  const params = new URLSearchParams(location.search);
  for (const input of document.querySelectorAll("#filters select, #filters input")) {
    if (params.has(input.name)) input.value = params.get(input.name);
    input.addEventListener("change", refresh);
  }
  refresh();
});
