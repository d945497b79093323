// DyKnow's web view: the live computation graph and its control panel (seed Ch. 5.2.2). It uses
// only the public HTTP API (`http-api.md`, `executors.md`, `groups.md`) and the change-set stream.
"use strict";

(function () {
  const $ = (id) => document.getElementById(id);
  const POLL_MS = 1000;
  const GHOST_MS = 10 * 60 * 1000; // how long a crashed CU stays on the graph

  const ui = {
    cus: [], targets: [], executors: [], groups: [], transformations: [], environment: null,
    changeSets: [], crashed: new Map(), known: new Map(), destroyed: new Set(),
    counters: new Map(), selected: null, refreshing: null, again: false,
    token: sessionStorage.getItem("dyknow-token") || "", live: false,
    groupStart: new Map(), errors: 0, changeToGraph: [],
  };

  // ---- HTTP ---------------------------------------------------------------------------------

  // A request to the service. Mutating requests carry the bearer token when the user gave one;
  // a 401 asks for it and tries once more. Resolves to {ok, status, json, text}.
  async function api(method, path, body, contentType, accept) {
    const send = async () => {
      const headers = {};
      if (contentType) headers["Content-Type"] = contentType;
      if (accept) headers["Accept"] = accept;
      if (method !== "GET" && ui.token) headers["Authorization"] = "Bearer " + ui.token;
      let r;
      try {
        r = await fetch(path, { method, headers, body });
      } catch (e) {
        return { ok: false, status: 0, json: { error: "the service cannot be reached: " + e.message }, text: "" };
      }
      const text = r.status === 204 ? "" : await r.text();
      let json = null;
      try { json = text ? JSON.parse(text) : null; } catch (_) { json = null; }
      return { ok: r.ok, status: r.status, json, text, type: r.headers.get("Content-Type") || "" };
    };
    let res = await send();
    if (res.status === 401 && method !== "GET") {
      const reason = "401 Unauthorized: " + ((res.json && res.json.error) || "this server needs a bearer token");
      if (await askToken(reason)) res = await send();
    }
    return res;
  }

  function askToken(reason) {
    return new Promise((resolve) => {
      const d = $("token-dialog");
      $("token-reason").textContent = reason || "The bearer token sent with every change (kept for this tab only).";
      $("token-input").value = ui.token;
      d.returnValue = "";
      d.addEventListener("close", function done() {
        d.removeEventListener("close", done);
        if (d.returnValue === "ok") {
          ui.token = $("token-input").value.trim();
          sessionStorage.setItem("dyknow-token", ui.token);
          resolve(true);
        } else resolve(false);
      });
      d.showModal();
      $("token-input").focus();
    });
  }

  const enc = encodeURIComponent;
  const getJson = async (path) => {
    const r = await api("GET", path);
    if (!r.ok) throw new Error(`${path}: ${r.status} ${(r.json && r.json.error) || r.text}`);
    return r.json;
  };

  // ---- DOM helpers --------------------------------------------------------------------------

  function h(tag, attrs, ...children) {
    const el = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (v == null || v === false) continue;
      if (k.startsWith("on")) el.addEventListener(k.slice(2), v);
      else if (k === "class") el.className = v;
      else if (k === "dataset") Object.assign(el.dataset, v);
      else el.setAttribute(k, v === true ? "" : v);
    }
    for (const c of children.flat()) {
      if (c == null || c === false) continue;
      el.append(c instanceof Node ? c : document.createTextNode(String(c)));
    }
    return el;
  }

  function say(text, kind) {
    const m = $("message");
    m.hidden = false;
    m.className = kind || "";
    m.textContent = text;
    clearTimeout(say.timer);
    if (kind !== "error") say.timer = setTimeout(() => { m.hidden = true; }, 6000);
  }

  // An error answer as the API gives it: the sentence, then each detail (a syntax error's line
  // and column with the offending line of `source` when known, or a violated constraint).
  function errorBox(res, source, name) {
    const box = h("div", { class: "error-box", role: "alert" });
    const status = res.status === 401 ? "401 Unauthorized" : res.status ? `${res.status}` : "no answer";
    box.append(h("strong", {}, `${name ? name + ": " : ""}${status}: ${(res.json && res.json.error) || res.text || "request failed"}`));
    const details = (res.json && res.json.details) || [];
    if (details.length) {
      const ul = h("ul", { class: "details" });
      for (const d of details) {
        if (d.line != null) {
          const li = h("li", { class: "syntax" }, `line ${d.line}, column ${d.column}: ${d.message || ""}`);
          const lines = source ? source.split("\n") : null;
          if (lines && lines[d.line - 1] != null) {
            li.append(h("pre", {}, lines[d.line - 1] + "\n" + " ".repeat(Math.max(0, (d.column || 1) - 1)) + "^"));
          }
          ul.append(li);
        } else if (d.constraint) {
          ul.append(h("li", {}, `${d.constraint}${d.subject ? " (" + d.subject + ")" : ""}`));
        } else {
          ul.append(h("li", {}, typeof d === "string" ? d : JSON.stringify(d)));
        }
      }
      box.append(ul);
    }
    return box;
  }

  // ---- refresh ------------------------------------------------------------------------------

  // Refreshes now, or right after the refresh under way (whose answers may predate the call);
  // the promise resolves once a refresh that started after the call has been drawn.
  function refreshSoon() {
    if (ui.refreshing) {
      ui.again = true;
      if (!ui.next) ui.next = new Promise((resolve) => { ui.nextResolve = resolve; });
      return ui.next;
    }
    ui.refreshing = refresh().finally(() => {
      ui.refreshing = null;
      if (ui.again) {
        const resolve = ui.nextResolve;
        ui.again = false; ui.next = null; ui.nextResolve = null;
        refreshSoon().then(resolve);
      }
    });
    return ui.refreshing;
  }

  async function refresh() {
    let cus, targets, environment, executors, groups;
    try {
      [cus, targets, environment, executors, groups] = await Promise.all([
        getJson("/cus?statistics=true"), getJson("/targets"), getJson("/environment"),
        getJson("/executors"), getJson("/groups"),
      ]);
    } catch (e) {
      ui.errors++;
      setLive(false, e.message);
      return;
    }
    const now = performance.now();
    for (const cu of cus) {
      cu.rates = {};
      cu.messages = 0;
      const ports = (cu.statistics && cu.statistics.ports) || {};
      for (const [port, s] of Object.entries(ports)) {
        cu.messages += s.messages || 0;
        const key = cu.name + "/" + port;
        const prev = ui.counters.get(key);
        if (prev && now > prev.at && s.messages >= prev.messages) {
          cu.rates[port] = (s.messages - prev.messages) / ((now - prev.at) / 1000);
        } else {
          cu.rates[port] = prev ? prev.rate : null;
        }
        ui.counters.set(key, { messages: s.messages || 0, at: now, rate: cu.rates[port] });
      }
      cu.cpu = cu.statistics && typeof cu.statistics.cpu_ms === "number" ? cu.statistics.cpu_ms : null;
    }
    noteCrashes(cus);
    ui.cus = cus; ui.targets = targets; ui.environment = environment; ui.executors = executors; ui.groups = groups;
    graph.update({ cus, targets, crashed: ui.crashed });
    renderHeader();
    renderActive();
    renderExecutors();
    renderGroups();
    renderConnectChoices();
    if (ui.selected) renderDetails(ui.selected, false);
  }

  // A CU that leaves the model without a change set destroying it crashed (`cu-crashed` removes
  // it at once, before the repair): it stays on the graph, red, where it was.
  function noteCrashes(cus) {
    const present = new Set(cus.map((c) => c.name));
    for (const [name, cu] of ui.known) {
      if (!present.has(name) && !ui.destroyed.has(name) && !ui.crashed.has(name)) {
        ui.crashed.set(name, { transformation: cu.transformation, executor: cu.executor, at: Date.now() });
      }
    }
    for (const cu of cus) if (cu.state === "crashed") ui.crashed.delete(cu.name);
    ui.known = new Map(cus.map((c) => [c.name, c]));
    for (const [name, g] of ui.crashed) {
      if (present.has(name) || Date.now() - g.at > GHOST_MS) ui.crashed.delete(name);
    }
  }

  function setLive(on, why) {
    ui.live = on;
    const p = $("live");
    p.textContent = on ? "live" : "offline";
    p.className = "pill " + (on ? "ok" : "no");
    p.title = on ? "receiving change sets as they happen" : "not connected: " + (why || "");
  }

  function renderHeader() {
    const env = ui.environment;
    if (!env) return;
    const s = $("env-status");
    s.textContent = env.valid ? "valid" : "invalid";
    s.className = "pill " + (env.valid ? "ok" : "no");
    const unsat = env.unsatisfied_targets || [];
    const cost = env.cost || {};
    const running = ui.cus.filter((c) => c.state === "running").length;
    $("env-detail").textContent = [
      `${ui.cus.length} CUs (${running} running)`,
      unsat.length ? `unsatisfied: ${unsat.join(", ")}` : "all targets satisfied",
      cost.upkeep_per_time_unit != null ? `upkeep ${Number(cost.upkeep_per_time_unit).toFixed(2)}/time unit` : null,
      env.phase ? `phase: ${env.phase}` : null,
      ui.crashed.size ? `${ui.crashed.size} crashed shown` : null,
    ].filter(Boolean).join(" · ");
  }

  // ---- panels: Active -----------------------------------------------------------------------

  function ports(cu) {
    const ins = Object.entries(cu.inputs).map(([p, c]) => `${c ?? "·"} → ${p}`);
    const outs = Object.entries(cu.outputs).map(([p, c]) => `${p} → ${c ?? "·"}`);
    return [...ins, ...outs].join("\n");
  }

  function renderActive() {
    if ($("panel-active").hidden) return;
    const filter = $("active-filter").value.trim().toLowerCase();
    const rows = [];
    const list = ui.cus.map((c) => ({ ...c })).concat([...ui.crashed].map(([name, g]) => ({
      name, transformation: g.transformation, state: "crashed", executor: g.executor, inputs: {}, outputs: {},
      cpu: null, messages: null })));
    list.sort((a, b) => a.name.localeCompare(b.name, undefined, { numeric: true }));
    for (const cu of list) {
      const text = `${cu.name} ${cu.transformation} ${cu.executor || ""} ${cu.state}`.toLowerCase();
      if (filter && !text.includes(filter)) continue;
      rows.push(h("tr", { dataset: { cu: cu.name }, class: ui.selected && ui.selected.id === "cu:" + cu.name ? "selected" : "" },
        h("td", {}, h("button", { class: "link", type: "button", onclick: () => selectNode("cu:" + cu.name) }, cu.name),
          h("div", { class: "hint" }, cu.transformation)),
        h("td", { class: "mono" }, ports(cu)),
        h("td", {}, h("span", { class: "state " + cu.state }, cu.state), h("div", { class: "hint" }, cu.executor || "")),
        h("td", {}, cu.cpu != null ? cu.cpu.toFixed(1) : ""),
        h("td", {}, cu.messages != null ? String(cu.messages) : "")));
    }
    $("active-rows").replaceChildren(...rows);
  }

  // ---- panels: Library ----------------------------------------------------------------------

  async function renderLibrary() {
    let tfs, targets;
    try { [tfs, targets] = await Promise.all([getJson("/transformations"), getJson("/targets")]); }
    catch (e) { say(e.message, "error"); return; }
    ui.transformations = tfs;
    const tags = (ports) => ports.map((p) => `${p.port}: ${p.tags.join(", ")}`).join("\n");
    $("library-rows").replaceChildren(...tfs.map((t) => h("tr", { dataset: { transformation: t.label } },
      h("td", {}, h("button", { class: "link", type: "button", onclick: () => showSpec(t) }, t.label)),
      h("td", { class: "mono" }, (tags(t.inputs) || "(source)") + "\n→ " + (tags(t.outputs) || "·")),
      h("td", {}, `${t.labour} / ${t.upkeep}`),
      h("td", {}, h("button", { class: "danger", type: "button", "aria-label": "delete " + t.label,
        onclick: () => removeSpec("transformations", t.label) }, "Delete")))));
    $("target-rows").replaceChildren(...targets.map((t) => h("tr", { dataset: { target: t.label } },
      h("td", {}, t.label, h("div", { class: "hint" }, t.tags.join(", "))),
      h("td", { class: "mono" }, t.channel),
      h("td", {}, t.satisfied ? h("span", { class: "verdict true" }, t.producer || "satisfied") : h("span", { class: "verdict false" }, "unsatisfied")),
      h("td", {}, h("button", { class: "danger", type: "button", "aria-label": "delete " + t.label,
        onclick: () => removeSpec("targets", t.label) }, "Delete")))));
    renderCreateChoices();
  }

  async function showSpec(t) {
    const r = await api("GET", "/transformations/" + enc(t.label));
    openDetails("Transformation " + t.label, [h("pre", {}, JSON.stringify(r.json, null, 2))]);
  }

  async function removeSpec(kind, label) {
    const r = await api("DELETE", `/${kind}/${enc(label)}`);
    if (r.ok) say(`${label} deleted`, "ok"); else $("import-result").replaceChildren(errorBox(r, null, label));
    renderLibrary();
    refreshSoon();
  }

  function detectKind(text) {
    if (/\b(ROSTarget|Target)\b/.test(text) && !/\bTransformation\b|hasTransformation|ROSTransformation/.test(text)) return "targets";
    if (/\bTransformation\b|ROSTransformation|hasInPort|hasOutPort/.test(text)) return "transformations";
    if (/subClassOf|owl:Class|similarTo/.test(text)) return "ontology";
    return "transformations";
  }

  async function importTurtle(e) {
    e.preventDefault();
    const out = $("import-result");
    out.replaceChildren();
    const sources = [];
    for (const f of $("import-file").files) sources.push({ name: f.name, text: await f.text() });
    const pasted = $("import-text").value;
    if (pasted.trim()) sources.push({ name: "pasted Turtle", text: pasted });
    if (!sources.length) { out.append(h("div", { class: "error-box" }, "Choose a Turtle file or paste Turtle first.")); return; }
    for (const s of sources) {
      const kind = $("import-kind").value === "auto" ? detectKind(s.text) : $("import-kind").value;
      const r = await api("POST", "/" + kind, s.text, "text/turtle");
      if (r.ok) {
        const what = r.json && r.json.labels ? r.json.labels.join(", ") : r.json && r.json.graph ? r.json.graph : "";
        out.append(h("div", { class: "ok-box" }, `${s.name}: ${kind} ${what}${r.json && r.json.replaced && r.json.replaced.length ? " (replaced " + r.json.replaced.join(", ") + ")" : ""}`));
      } else {
        out.append(errorBox(r, s.text, s.name));
      }
    }
    $("import-file").value = "";
    renderLibrary();
    refreshSoon();
  }

  // ---- panels: Create, Connect --------------------------------------------------------------

  function renderCreateChoices() {
    const sel = $("create-transformation");
    const cur = sel.value;
    sel.replaceChildren(...ui.transformations.map((t) => h("option", { value: t.label }, t.label)));
    if (cur) sel.value = cur;
  }

  async function createCu(e) {
    e.preventDefault();
    const body = { transformation: $("create-transformation").value, protected: $("create-protected").checked };
    if ($("create-name").value.trim()) body.name = $("create-name").value.trim();
    const r = await api("POST", "/cus", JSON.stringify(body), "application/json");
    if (r.ok) { say(`spawned ${r.json.name}`, "ok"); $("create-name").value = ""; }
    else errorAsMessage(r);
    refreshSoon();
  }

  // Shows an error answer in the message line above the panels (it stays until the next one).
  function errorAsMessage(r) {
    const m = $("message");
    const box = errorBox(r);
    clearTimeout(say.timer);
    m.hidden = false;
    m.className = "error";
    m.replaceChildren(...box.childNodes);
  }

  function channelNames() {
    const names = new Set();
    for (const cu of ui.cus) for (const c of [...Object.values(cu.inputs), ...Object.values(cu.outputs)]) if (c) names.add(c);
    for (const t of ui.targets) names.add(t.channel);
    return [...names].sort();
  }

  function renderConnectChoices() {
    const keep = (sel, options) => {
      const cur = sel.value;
      const same = sel.options.length === options.length && options.every((o, i) => sel.options[i].value === o.value);
      if (!same) sel.replaceChildren(...options.map((o) => h("option", { value: o.value }, o.label)));
      if (cur && options.some((o) => o.value === cur)) sel.value = cur;
    };
    keep($("connect-cu"), ui.cus.map((c) => ({ value: c.name, label: `${c.name} (${c.transformation})` })));
    updatePorts();
    const outs = [], ins = [];
    for (const c of ui.cus) {
      for (const [p, ch] of Object.entries(c.outputs)) outs.push({ value: `${c.name}\u0000${p}`, label: `${c.name}.${p}${ch ? " → " + ch : ""}` });
      for (const [p, ch] of Object.entries(c.inputs)) ins.push({ value: `${c.name}\u0000${p}`, label: `${c.name}.${p}${ch ? " ← " + ch : ""}` });
    }
    keep($("link-from"), outs);
    keep($("link-to"), ins);
    const dl = $("channel-names");
    const names = channelNames();
    if (dl.options.length !== names.length) dl.replaceChildren(...names.map((n) => h("option", { value: n })));
  }

  function updatePorts() {
    const cu = ui.cus.find((c) => c.name === $("connect-cu").value);
    const sel = $("connect-port");
    const cur = sel.value;
    const opts = cu ? [
      ...Object.entries(cu.inputs).map(([p, ch]) => ({ value: "in\u0000" + p, label: `in ${p} (${ch ?? "unbound"})` })),
      ...Object.entries(cu.outputs).map(([p, ch]) => ({ value: "out\u0000" + p, label: `out ${p} (${ch ?? "unbound"})` })),
    ] : [];
    const same = sel.options.length === opts.length && opts.every((o, i) => sel.options[i].value === o.value && sel.options[i].textContent === o.label);
    if (!same) sel.replaceChildren(...opts.map((o) => h("option", { value: o.value }, o.label)));
    if (cur && opts.some((o) => o.value === cur)) sel.value = cur;
  }

  async function setConfig(cu, dir, port, channel) {
    const body = { inputs: {}, outputs: {} };
    body[dir === "in" ? "inputs" : "outputs"][port] = channel;
    return api("PUT", `/cus/${enc(cu)}/config`, JSON.stringify(body), "application/json");
  }

  async function connectPort(e) {
    e.preventDefault();
    const [dir, port] = $("connect-port").value.split("\u0000");
    const channel = $("connect-channel").value.trim() || null;
    const r = await setConfig($("connect-cu").value, dir, port, channel);
    if (r.ok) say(`${$("connect-cu").value}.${port} ${channel ? "→ " + channel : "unbound"}`, "ok");
    else errorAsMessage(r);
    refreshSoon();
  }

  async function linkPorts(e) {
    e.preventDefault();
    const [from, out] = $("link-from").value.split("\u0000");
    const [to, inp] = $("link-to").value.split("\u0000");
    const producer = ui.cus.find((c) => c.name === from);
    let channel = producer && producer.outputs[out];
    if (!channel) {
      channel = `/ui/${from}/${out}`.replace(/[*$?#\s]/g, "_");
      const r = await setConfig(from, "out", out, channel);
      if (!r.ok) { errorAsMessage(r); return; }
    }
    const r = await setConfig(to, "in", inp, channel);
    if (r.ok) say(`${from}.${out} → ${channel} → ${to}.${inp}`, "ok"); else errorAsMessage(r);
    refreshSoon();
  }

  // ---- panels: Change sets ------------------------------------------------------------------

  // A change set's causes: its `cause`, then the others its review served (`other_causes`).
  function causesOf(cs) {
    return [cs.cause, ...(cs.other_causes || [])].filter(Boolean);
  }

  function describeCause(c) {
    if (!c) return "";
    const also = (c.also || []).length ? ` and ${c.also.length} more` : "";
    const cus = c.cus ? " " + c.cus.join(" ") : "";
    return c.kind + (c.target ? " " + c.target : "") + (c.cu ? " " + c.cu : "") + also + cus;
  }

  function describeAction(a) {
    const rest = [a.cu, a.transformation ? `(${a.transformation})` : null, a.port ? `.${a.port}` : null,
      a.channel ? `→ ${a.channel}` : null, a.target, a.label].filter(Boolean).join(" ");
    return `${a.action} ${rest}`;
  }

  function changeSetItem(cs, fresh) {
    const actions = cs.actions || [];
    const delta = cs.delta || {};
    return h("li", { class: fresh ? "fresh" : "", dataset: { id: cs.id } },
      h("div", { class: "head" },
        h("strong", {}, cs.id),
        h("span", { class: "hint" }, new Date(cs.at).toLocaleTimeString()),
        h("span", { class: "cause" }, causesOf(cs).map(describeCause).join(", ")),
        cs.cost ? h("span", { class: "hint" }, `cost ${Number(cs.cost.total).toFixed(2)}`) : null,
        cs.status ? h("span", { class: "verdict " + (cs.status === "applied" ? "true" : cs.status === "failed" ? "false" : "pending") }, cs.status) : null),
      actions.length ? h("ul", { class: "actions" }, actions.map((a) => h("li", {},
        a.cu ? h("button", { class: "link", type: "button", onclick: () => selectNode("cu:" + a.cu) }, describeAction(a)) : describeAction(a),
        a.reason ? h("span", { class: "hint" }, " " + a.reason) : null))) : h("div", { class: "hint" }, "no actions"),
      (delta.insert || delta.delete) ? h("details", {}, h("summary", {}, "RDF delta"),
        delta.delete ? h("div", {}, h("div", { class: "hint" }, "delete"), h("pre", {}, delta.delete)) : null,
        delta.insert ? h("div", {}, h("div", { class: "hint" }, "insert"), h("pre", {}, delta.insert)) : null) : null);
  }

  function renderTimeline() {
    const items = ui.changeSets.slice(-200).reverse().map((cs) => changeSetItem(cs, cs.fresh));
    $("timeline").replaceChildren(...items);
  }

  function noteChangeSet(cs, fresh) {
    const seen = ui.changeSets.find((c) => c.id === cs.id);
    if (seen && seen.at === cs.at) return;
    // The same id made at another time: the service's history is another one (an in-memory
    // service restarted, and its ids began again). The old timeline is forgotten, or the new
    // change sets would be dropped as seen.
    if (seen) ui.changeSets = [];
    cs.fresh = fresh;
    ui.changeSets.push(cs);
    for (const a of cs.actions || []) if (a.action === "destroy" && a.cu) { ui.destroyed.add(a.cu); ui.crashed.delete(a.cu); }
    for (const c of causesOf(cs)) {
      // CUs replaced because their transformation's spec changed left the model first: not crashes.
      if (c.kind === "spec-changed") for (const cu of c.cus || []) { ui.destroyed.add(cu); ui.crashed.delete(cu); }
      // Every CU a crash review repairs: the first (`cu`) and the others of the burst (`also`).
      if (c.kind === "cu-crashed") for (const cu of [c.cu, ...(c.also || [])]) {
        if (!cu || !ui.known.has(cu) || ui.crashed.has(cu)) continue;
        const k = ui.known.get(cu);
        ui.crashed.set(cu, { transformation: k.transformation, executor: k.executor, at: Date.now() });
      }
    }
    if (fresh) graph.flash((cs.actions || []).map((a) => a.cu).filter(Boolean));
  }

  // On (re)connecting: the change sets the page has not seen. After a reconnection the whole
  // history is read: if it no longer holds the page's last change set as it was (the service
  // restarted in memory, its ids began again), the timeline starts over from it.
  async function catchUp() {
    const last = ui.changeSets.length ? ui.changeSets[ui.changeSets.length - 1] : null;
    try {
      const list = await getJson("/changesets");
      const mine = last && list.find((c) => c.id === last.id);
      if (last && (!mine || mine.at !== last.at)) ui.changeSets = [];
      const from = mine && mine.at === last.at ? list.indexOf(mine) + 1 : 0;
      for (const cs of list.slice(from)) noteChangeSet(cs, !!last);
      renderTimeline();
    } catch (e) { say(e.message, "error"); }
  }

  function listen() {
    const es = new EventSource("/changesets/stream");
    es.addEventListener("open", () => { setLive(true); catchUp(); refreshSoon(); });
    es.addEventListener("changeset", (ev) => {
      let cs;
      try { cs = JSON.parse(ev.data); } catch (_) { return; }
      noteChangeSet(cs, true);
      renderTimeline();
      // How long the graph takes to show a change set (the 500-CU benchmark reads it).
      const since = performance.now();
      refreshSoon().then(() => {
        ui.changeToGraph.push(performance.now() - since);
        if (ui.changeToGraph.length > 500) ui.changeToGraph.shift();
      });
    });
    es.addEventListener("error", () => setLive(false, "the change-set stream was interrupted; reconnecting"));
  }

  // ---- panels: Groups -----------------------------------------------------------------------

  function renderGroups() {
    if ($("panel-groups").hidden) return;
    const list = ui.groups.map((g) => {
      const lastT = g.last_t;
      if (lastT != null && !ui.groupStart.has(g.label)) ui.groupStart.set(g.label, lastT);
      let start = ui.groupStart.get(g.label);
      for (const f of g.formulas) if (f.t != null && (start == null || f.t < start)) start = f.t;
      const span = lastT != null && start != null ? Math.max(1, lastT - start) : null;
      const formulas = g.formulas.map((f) => {
        const verdict = f.verdict || "pending";
        const strip = h("div", { class: "strip", title: f.t != null ? `decided at t=${f.t}` : "undecided" });
        if (span != null) {
          const at = f.t != null ? (f.t - start) / span : 1;
          strip.append(h("span", { class: "pending", style: `left:0;width:${(100 * Math.min(1, at)).toFixed(1)}%` }));
          if (f.t != null) strip.append(h("span", { class: verdict, style: `left:${(100 * at).toFixed(1)}%;width:${(100 * (1 - at)).toFixed(1)}%;min-width:4px` }));
        }
        return h("div", { class: "formula", dataset: { index: f.index } },
          h("code", {}, `${f.index}: ${f.formula}`),
          h("span", { class: "verdict " + verdict, dataset: { verdict } }, verdict),
          h("button", { type: "button", class: "danger", "aria-label": `remove formula ${f.index}`,
            onclick: () => groupAction("DELETE", `/groups/${enc(g.label)}/formulas/${f.index}`) }, "✕"),
          strip);
      });
      const symbols = (g.symbols || []).map((s) => h("li", {},
        h("code", {}, s.symbol), " ", s.satisfied ? h("span", { class: "verdict true" }, "satisfied") : h("span", { class: "verdict false" }, "unsatisfied"),
        h("span", { class: "hint" }, ` ${s.channel} · ${s.samples} samples · ${s.late} late · ${s.missing_states} missing`)));
      return h("div", { class: "group", dataset: { group: g.label } },
        h("div", { class: "head" }, h("strong", {}, g.label), h("span", { class: "pill" }, g.state),
          h("span", { class: "hint" }, `${g.states} states · ${g.result_channel}`),
          h("span", { class: "spacer" }),
          g.state === "created" ? h("button", { type: "button", onclick: () => groupAction("POST", `/groups/${enc(g.label)}/start`) }, "Start") : null,
          g.state === "running" ? h("button", { type: "button", onclick: () => groupAction("POST", `/groups/${enc(g.label)}/stop`) }, "Stop") : null,
          h("button", { type: "button", class: "danger", onclick: () => groupAction("DELETE", `/groups/${enc(g.label)}`) }, "Destroy")),
        formulas,
        // A stopped group takes no formula (409): no form for it.
        g.state === "stopped" ? null : h("form", { class: "add-formula", onsubmit: (e) => addFormula(e, g.label) },
          h("label", {}, h("input", { placeholder: "add a formula", "aria-label": "formula to add to " + g.label }), h("button", { type: "submit" }, "Add"))),
        symbols.length ? h("details", {}, h("summary", {}, `${symbols.length} symbols`), h("ul", {}, symbols)) : null);
    });
    const open = new Set([...document.querySelectorAll("#group-list details[open]")].map((d) => d.closest("[data-group]").dataset.group));
    const focused = document.activeElement && document.activeElement.closest && document.activeElement.closest("#group-list form");
    if (focused) return; // do not take the text from under the user's cursor
    $("group-list").replaceChildren(...(list.length ? list : [h("p", { class: "hint" }, "No groups yet.")]));
    for (const d of document.querySelectorAll("#group-list [data-group]")) if (open.has(d.dataset.group)) { const x = d.querySelector("details"); if (x) x.open = true; }
  }

  async function groupAction(method, path) {
    const r = await api(method, path);
    if (!r.ok) errorAsMessage(r);
    refreshSoon();
  }

  async function addFormula(e, label) {
    e.preventDefault();
    const input = e.target.querySelector("input");
    const r = await api("POST", `/groups/${enc(label)}/formulas`, JSON.stringify({ formula: input.value }), "application/json");
    if (r.ok) input.value = ""; else errorAsMessage(r);
    input.blur();
    refreshSoon();
  }

  async function createGroup(e) {
    e.preventDefault();
    const policy = $("group-policy").value;
    const period = Number($("group-period").value) || 100;
    // Left empty, the service's default; for hold the field is the max age (groups.md), for
    // wait and event the max delay.
    const field = $("group-max").value.trim();
    const sync = policy === "event" ? { policy } : { policy, period_ms: period };
    if (field !== "") sync[policy === "hold" ? "max_age_ms" : "max_delay_ms"] = Number(field);
    const body = {
      formulas: $("group-formulas").value.split("\n").map((s) => s.trim()).filter(Boolean),
      sync, start: $("group-start").checked,
    };
    if ($("group-label").value.trim()) body.label = $("group-label").value.trim();
    const r = await api("POST", "/groups", JSON.stringify(body), "application/json");
    // The answer goes above the list, which every refresh redraws (an error put in the list
    // was wiped at once: a user audit never saw one).
    if (r.ok) {
      say(`group ${r.json.label} created`, "ok"); $("group-formulas").value = ""; $("group-label").value = "";
      $("group-result").replaceChildren();
    } else $("group-result").replaceChildren(errorBox(r, null, "group"));
    refreshSoon();
  }

  // ---- panels: Query, Executors -------------------------------------------------------------

  async function runQuery(e) {
    e.preventDefault();
    const q = $("query-text").value;
    const t0 = performance.now();
    const r = await api("POST", "/sparql", q, "application/sparql-query", "application/sparql-results+json, text/turtle;q=0.9");
    const ms = performance.now() - t0;
    const out = $("query-result");
    if (!r.ok) { out.replaceChildren(errorBox(r, q, "query")); $("query-info").textContent = ""; return; }
    if (r.json && r.json.head && r.json.results) {
      const vars = r.json.head.vars;
      const rows = r.json.results.bindings;
      const cell = (b) => b == null ? "" : b.type === "uri" ? b.value.replace(/^.*[#/](?=[^#/]+$)/, "") : b.value;
      out.replaceChildren(h("table", { class: "list" },
        h("thead", {}, h("tr", {}, vars.map((v) => h("th", {}, "?" + v)))),
        h("tbody", {}, rows.map((b) => h("tr", {}, vars.map((v) => h("td", { title: b[v] ? b[v].value : "" }, cell(b[v]))))))));
      $("query-info").textContent = `${rows.length} rows in ${ms.toFixed(0)} ms`;
    } else if (r.json && typeof r.json.boolean === "boolean") {
      out.replaceChildren(h("p", {}, String(r.json.boolean)));
      $("query-info").textContent = `${ms.toFixed(0)} ms`;
    } else {
      out.replaceChildren(h("pre", {}, r.text));
      $("query-info").textContent = `${ms.toFixed(0)} ms`;
    }
  }

  function renderExecutors() {
    const sel = $("executor-filter");
    const names = ui.executors.map((e) => e.name);
    if (sel.options.length !== names.length + 1) {
      const cur = sel.value;
      sel.replaceChildren(h("option", { value: "" }, "all"), ...names.map((n) => h("option", { value: n }, n)));
      sel.value = names.includes(cur) ? cur : "";
    }
    if ($("panel-executors").hidden) return;
    $("executor-rows").replaceChildren(...ui.executors.map((e) => h("tr", { dataset: { executor: e.name } },
      h("td", {}, h("button", { class: "link", type: "button", onclick: () => { sel.value = e.name; graph.setExecutor(e.name); } }, e.name)),
      h("td", {}, e.present ? h("span", { class: "verdict true" }, "present") : h("span", { class: "verdict false" }, "gone")),
      h("td", {}, String(e.cus.length)),
      h("td", { class: "hint" }, e.transformations.join(", ")))));
  }

  // ---- details ------------------------------------------------------------------------------

  function openDetails(title, body) {
    $("details-title").textContent = title;
    $("details-body").replaceChildren(...body);
    $("details").hidden = false;
  }

  function selectNode(id) {
    graph.select(id);
    const el = graph.cy.getElementById(id);
    if (el.nonempty()) renderDetails(el.data(), true);
  }

  function touching(pred) {
    return ui.changeSets.filter((cs) => (cs.actions || []).some(pred)).slice(-20).reverse();
  }

  async function renderDetails(data, fresh) {
    if (!data) { ui.selected = null; $("details").hidden = true; return; }
    ui.selected = data;
    if (!fresh && $("details").hidden) return;
    const dl = (pairs) => h("dl", {}, pairs.filter(([, v]) => v != null && v !== "").flatMap(([k, v]) => [h("dt", {}, k), h("dd", {}, v)]));
    const history = (list) => list.length ? h("div", {}, h("h3", {}, "Change sets"),
      h("ul", { class: "actions" }, list.map((cs) => h("li", {}, `${cs.id} · ${causesOf(cs).map(describeCause).join(", ")} · `,
        (cs.actions || []).filter((a) => a.cu === data.name || a.channel === data.name).map(describeAction).join("; "))))) : null;
    if (data.kind === "cu") {
      const cu = ui.cus.find((c) => c.name === data.name);
      const ghost = ui.crashed.get(data.name);
      if (!cu) {
        openDetails("CU " + data.name, [dl([["state", "crashed"], ["transformation", ghost && ghost.transformation], ["executor", ghost && ghost.executor],
          ["crashed at", ghost && new Date(ghost.at).toLocaleTimeString()]]), history(touching((a) => a.cu === data.name))]);
        return;
      }
      const st = cu.statistics || {};
      const portRows = [...Object.entries(cu.inputs).map(([p, c]) => ["in " + p, c]), ...Object.entries(cu.outputs).map(([p, c]) => ["out " + p, c])]
        .map(([p, c]) => {
          const s = (st.ports || {})[p.split(" ")[1]] || {};
          const r = cu.rates[p.split(" ")[1]];
          return h("tr", {}, h("td", {}, p), h("td", { class: "mono" }, c ?? "unbound"), h("td", {}, String(s.messages ?? 0)),
            h("td", {}, r != null ? r.toFixed(1) : ""));
        });
      const body = [
        dl([["transformation", cu.transformation], ["state", h("span", { class: "state " + cu.state }, cu.state)], ["executor", cu.executor],
          ["protected", cu.protected ? "yes" : "no"], ["upkeep estimate", String(cu.upkeep)], ["uptime", st.uptime_ms != null ? (st.uptime_ms / 1000).toFixed(1) + " s" : null],
          ["CPU", cu.cpu != null ? cu.cpu.toFixed(1) + " ms" : null], ["reconfigurations", st.reconfigurations != null ? String(st.reconfigurations) : null],
          ["pid", cu.pid != null ? String(cu.pid) : null]]),
        h("table", { class: "list" }, h("thead", {}, h("tr", {}, h("th", {}, "port"), h("th", {}, "channel"), h("th", {}, "messages"), h("th", {}, "msg/s"))), h("tbody", {}, portRows)),
        h("div", {}, h("button", { type: "button", onclick: () => { const t = ui.transformations.find((x) => x.label === cu.transformation); showSpec(t || { label: cu.transformation }); } }, "Spec"),
          " ", h("button", { type: "button", class: "danger", onclick: async () => { const r = await api("DELETE", "/cus/" + enc(cu.name)); if (!r.ok) errorAsMessage(r); refreshSoon(); } }, "Destroy")),
        history(touching((a) => a.cu === cu.name)),
      ];
      openDetails("CU " + cu.name, body);
    } else {
      const name = data.name;
      const consumers = ui.cus.filter((c) => Object.values(c.inputs).includes(name)).map((c) => c.name);
      const targets = ui.targets.filter((t) => t.channel === name);
      openDetails("Channel " + name, [
        dl([["producer", data.producer || "none"], ["consumers", consumers.join(", ") || "none"],
          ["rate", data.rate != null ? data.rate.toFixed(1) + " msg/s" : null],
          ["targets", targets.map((t) => `${t.label} (${t.satisfied ? "satisfied" : "unsatisfied"})`).join(", ")]]),
        history(touching((a) => a.channel === name)),
      ]);
    }
  }

  // ---- wiring -------------------------------------------------------------------------------

  function showPanel(name) {
    for (const b of document.querySelectorAll("#tabs [role=tab]")) {
      const on = b.dataset.panel === name;
      b.setAttribute("aria-selected", on ? "true" : "false");
      b.tabIndex = on ? 0 : -1;
      $("panel-" + b.dataset.panel).hidden = !on;
    }
    if (name === "library" || name === "create") renderLibrary();
    if (name === "changesets") renderTimeline();
    renderActive(); renderGroups(); renderExecutors();
  }

  function applyTheme(theme) {
    document.documentElement.dataset.theme = theme;
    localStorage.setItem("dyknow-theme", theme);
    graph.restyle();
  }

  let graph;
  function start() {
    const saved = localStorage.getItem("dyknow-theme");
    document.documentElement.dataset.theme = saved || (matchMedia("(prefers-color-scheme: dark)").matches ? "dark" : "light");
    graph = DyGraph.create($("cy"), { select: (d) => d ? renderDetails(d, true) : renderDetails(null) });
    window.dyknowUi = { graph, ui, refresh: refreshSoon, noteChangeSet };
    for (const b of document.querySelectorAll("#tabs [role=tab]")) b.addEventListener("click", () => showPanel(b.dataset.panel));
    $("tabs").addEventListener("keydown", (e) => {
      const tabs = [...document.querySelectorAll("#tabs [role=tab]")];
      const i = tabs.indexOf(document.activeElement);
      if (i < 0 || !["ArrowRight", "ArrowLeft"].includes(e.key)) return;
      const next = tabs[(i + (e.key === "ArrowRight" ? 1 : tabs.length - 1)) % tabs.length];
      next.focus(); showPanel(next.dataset.panel);
    });
    $("fit").addEventListener("click", () => graph.fit());
    $("relayout").addEventListener("click", () => graph.relayout());
    $("orientation").addEventListener("click", () => {
      const dir = graph.orientation() === "LR" ? "TB" : "LR";
      graph.setOrientation(dir);
      $("orientation").textContent = dir === "LR" ? "Top → bottom" : "Left → right";
    });
    $("executor-filter").addEventListener("change", (e) => graph.setExecutor(e.target.value));
    $("hide-idle").addEventListener("change", (e) => graph.setHideIdle(e.target.checked));
    $("clear-crashed").addEventListener("click", () => { ui.crashed.clear(); refreshSoon(); });
    $("details-close").addEventListener("click", () => renderDetails(null));
    $("active-filter").addEventListener("input", renderActive);
    $("import-form").addEventListener("submit", importTurtle);
    $("create-form").addEventListener("submit", createCu);
    $("connect-cu").addEventListener("change", updatePorts);
    $("connect-form").addEventListener("submit", connectPort);
    $("link-form").addEventListener("submit", linkPorts);
    $("group-form").addEventListener("submit", createGroup);
    const policyFields = () => {
      const policy = $("group-policy").value;
      $("group-max-name").textContent = policy === "hold" ? "Max age ms" : "Max delay ms";
      $("group-period").disabled = policy === "event";
    };
    $("group-policy").addEventListener("change", policyFields);
    policyFields();
    $("query-form").addEventListener("submit", runQuery);
    $("token-button").addEventListener("click", () => askToken());
    $("theme-button").addEventListener("click", () => applyTheme(document.documentElement.dataset.theme === "dark" ? "light" : "dark"));
    showPanel("active");
    listen();
    refreshSoon();
    poll();
  }

  // One poll a second, or less often while the service is slow to answer: the page never keeps
  // it busy more than a third of the time.
  function poll() {
    setTimeout(async () => {
      const t0 = performance.now();
      await refreshSoon();
      ui.pollMs = Math.min(30000, Math.max(POLL_MS, 2 * (performance.now() - t0)));
      poll();
    }, ui.pollMs || POLL_MS);
  }

  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", start);
  else start();
})();
