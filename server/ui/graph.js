// The computation graph (seed Ch. 5.2.2, Figure 5.3): CUs as ovals, channels as rectangles,
// targets marked on their channels. Updates change nodes in place; a full layered layout runs
// only on the first load, when most of the graph is new, or when asked, and never moves a node
// the user pinned by dragging it. New nodes are placed next to their neighbours, so a repair
// does not move the rest of the graph.
"use strict";

(function () {
  const RANK_GAP = 90;   // between a node and its neighbour's layer
  const NODE_GAP = 14;   // between two nodes of one layer

  function css(name) {
    return getComputedStyle(document.documentElement).getPropertyValue(name).trim();
  }

  function style() {
    const c = (n) => css(n);
    return [
      { selector: "node", style: {
        "label": "data(label)", "text-wrap": "wrap", "text-valign": "center", "text-halign": "center",
        "font-size": 11, "font-family": "Liberation Sans, sans-serif", "color": c("--fg"), "width": "data(w)", "height": "data(h)",
        "border-width": 2, "transition-property": "background-color, border-color, opacity",
        "transition-duration": "0.3s" } },
      { selector: "node.cu", style: {
        "shape": "ellipse", "background-color": c("--bg"), "border-color": c("--running"),
        "border-width": 3 } },
      { selector: "node.cu[state = 'running']", style: { "border-color": c("--running"), "background-color": mix(c("--running"), c("--bg")) } },
      { selector: "node.cu[state = 'starting']", style: { "border-color": c("--starting"), "background-color": mix(c("--starting"), c("--bg")) } },
      { selector: "node.cu[state = 'stopped']", style: { "border-color": c("--stopped"), "background-color": mix(c("--stopped"), c("--bg")) } },
      { selector: "node.cu[state = 'model']", style: { "border-color": c("--model"), "background-color": mix(c("--model"), c("--bg")) } },
      { selector: "node.cu[state = 'crashed']", style: { "border-color": c("--crashed"), "background-color": c("--crashed"),
        "color": "#ffffff", "border-style": "double", "border-width": 5 } },
      { selector: "node.channel", style: {
        "shape": "round-rectangle", "background-color": c("--channel"), "border-color": c("--channel-line"),
        "border-width": 1.5, "font-size": 10.5 } },
      { selector: "node.channel.idle", style: { "opacity": 0.7 } },
      { selector: "node.channel.target", style: { "border-width": 4, "border-color": c("--ok") } },
      { selector: "node.channel.target.unsatisfied", style: { "border-color": c("--no"), "border-style": "dashed" } },
      { selector: "edge", style: {
        "width": 1.6, "curve-style": "bezier", "target-arrow-shape": "triangle", "arrow-scale": 0.9,
        "line-color": c("--edge"), "target-arrow-color": c("--edge"), "label": "data(port)",
        "font-size": 9, "color": c("--muted"), "text-rotation": "autorotate", "min-zoomed-font-size": 8,
        "text-background-color": c("--bg"), "text-background-opacity": 0.8, "text-background-padding": 1 } },
      { selector: ".faded", style: { "opacity": 0.18 } },
      { selector: "node.hl", style: { "underlay-color": c("--hl"), "underlay-opacity": 0.25, "underlay-padding": 5 } },
      { selector: "edge.hl", style: { "line-color": c("--hl"), "target-arrow-color": c("--hl"), "width": 2.6 } },
      { selector: "node:selected", style: { "overlay-color": c("--hl"), "overlay-opacity": 0.18, "overlay-padding": 6 } },
      { selector: "node.pinned", style: { "outline-width": 0, "border-style": "solid" } },
      { selector: ".hidden", style: { "display": "none" } },
      { selector: "node.flash", style: { "underlay-color": c("--focus"), "underlay-opacity": 0.45, "underlay-padding": 8 } },
    ];
  }

  // A light tint of a colour for node fills (both themes keep text readable on it).
  function mix(color, bg) {
    const p = (s) => {
      const m = /^#?([0-9a-f]{6})$/i.exec(s);
      return m ? [0, 2, 4].map((i) => parseInt(m[1].slice(i, i + 2), 16)) : [128, 128, 128];
    };
    const a = p(color), b = p(bg);
    const r = a.map((v, i) => Math.round(v * 0.18 + b[i] * 0.82));
    return "#" + r.map((v) => v.toString(16).padStart(2, "0")).join("");
  }

  function textSize(lines, font) {
    const longest = Math.max(...lines.map((l) => l.length));
    return { w: Math.max(40, longest * font * 0.58), h: lines.length * font * 1.3 };
  }

  function rate(r) {
    if (r == null) return "";
    return r >= 10 ? `${Math.round(r)} msg/s` : `${r.toFixed(1)} msg/s`;
  }

  // The graph's elements for a view of the service: CUs, their channels, the targets' channels,
  // crashed CUs still shown. Returns id → element definition.
  function elements(view) {
    const out = new Map();
    const channel = (name) => {
      const id = "ch:" + name;
      if (!out.has(id)) out.set(id, { group: "nodes", data: { id, kind: "channel", name, targets: [] }, classes: "channel" });
      return out.get(id);
    };
    for (const cu of view.cus) {
      const id = "cu:" + cu.name;
      out.set(id, { group: "nodes", classes: "cu", data: {
        id, kind: "cu", name: cu.name, transformation: cu.transformation, state: cu.state,
        executor: cu.executor || "", cpu: cu.cpu, messages: cu.messages } });
      for (const [port, ch] of Object.entries(cu.outputs)) {
        if (ch == null) continue;
        channel(ch).data.producer = cu.name;
        channel(ch).data.rate = cu.rates ? cu.rates[port] : null;
        out.set(`e:${cu.name}>${port}`, { group: "edges", data: { id: `e:${cu.name}>${port}`, source: id, target: "ch:" + ch, port } });
      }
      for (const [port, ch] of Object.entries(cu.inputs)) {
        if (ch == null) continue;
        channel(ch);
        out.set(`e:${cu.name}<${port}`, { group: "edges", data: { id: `e:${cu.name}<${port}`, source: "ch:" + ch, target: id, port } });
      }
    }
    for (const t of view.targets) {
      const c = channel(t.channel);
      c.data.targets.push(t.label);
      c.data.satisfied = (c.data.satisfied !== false) && t.satisfied;
    }
    for (const [name, ghost] of view.crashed) {
      const id = "cu:" + name;
      if (out.has(id)) continue;
      out.set(id, { group: "nodes", classes: "cu", data: {
        id, kind: "cu", name, transformation: ghost.transformation, state: "crashed",
        executor: ghost.executor || "", cpu: null, messages: null } });
    }
    for (const el of out.values()) {
      if (el.group !== "nodes") continue;
      const d = el.data;
      let lines;
      if (d.kind === "cu") {
        const status = [d.state, d.executor, d.cpu != null ? `${d.cpu.toFixed(0)} ms CPU` : null].filter(Boolean).join(" · ");
        lines = [d.name, d.transformation, status];
        const s = textSize(lines, 11);
        d.w = s.w + 26; d.h = s.h + 16;
      } else {
        const idle = !(d.rate > 0);
        d.idle = idle;
        lines = [d.name];
        if (d.producer) lines.push(rate(d.rate || 0));
        if (d.targets.length) lines.push("◎ " + d.targets.join(", ") + (d.satisfied ? "" : " (unsatisfied)"));
        const s = textSize(lines, 10.5);
        d.w = s.w + 16; d.h = s.h + 10;
        el.classes = "channel" + (idle ? " idle" : "") + (d.targets.length ? " target" : "") + (d.targets.length && !d.satisfied ? " unsatisfied" : "");
      }
      d.label = lines.join("\n");
    }
    return out;
  }

  function create(container, callbacks) {
    const cy = cytoscape({
      container, style: style(), elements: [], wheelSensitivity: 0.3, minZoom: 0.05, maxZoom: 4,
      boxSelectionEnabled: false, textureOnViewport: true, hideEdgesOnViewport: false,
    });
    const state = {
      rankDir: "LR", pinned: new Set(), executor: "", hideIdle: false, laidOut: false, big: false,
      metrics: { updates: [], layouts: [] },
    };

    cy.on("dragfree", "node", (e) => { state.pinned.add(e.target.id()); e.target.addClass("pinned"); });
    cy.on("mouseover", "node", (e) => highlight(e.target));
    cy.on("mouseout", "node", () => cy.elements().removeClass("hl faded"));
    cy.on("tap", "node", (e) => callbacks.select && callbacks.select(e.target.data()));
    cy.on("tap", (e) => { if (e.target === cy && callbacks.select) callbacks.select(null); });

    // Upstream and downstream of a node: what it depends on and what depends on it (dependsOn
    // is hasSubscription ∘ fromCU, transitively: the graph's paths).
    function highlight(node) {
      cy.batch(() => {
        const related = node.predecessors().union(node.successors()).union(node);
        cy.elements().not(related).addClass("faded");
        related.addClass("hl");
      });
    }

    function layoutOptions(extra) {
      return Object.assign({
        name: "dagre", rankDir: state.rankDir, nodeSep: 18, rankSep: 45, edgeSep: 8,
        fit: false, animate: true, animationDuration: 400, padding: 30,
      }, extra);
    }

    function fullLayout(first) {
      const t0 = performance.now();
      const eles = cy.elements().not(cy.nodes().filter((n) => state.pinned.has(n.id())));
      // The area per node of a fresh layout, at its end (the animation moves the nodes).
      eles.layout(layoutOptions(Object.assign(first ? { animate: false, fit: true } : {}, {
        stop: () => { state.spread = spread(); },
      }))).run();
      state.metrics.layouts.push(performance.now() - t0);
      state.laidOut = true;
    }

    // The drawing's area per node.
    function spread() {
      const n = cy.nodes().length;
      if (!n) return null;
      const bb = cy.nodes().boundingBox({ includeLabels: false, includeOverlays: false });
      return (bb.w * bb.h) / n;
    }

    // Places each new node beside its placed neighbours: one layer after its producers (or
    // before its consumers), at their mean height, moved down past any node it would overlap.
    function placeNew(nodes) {
      const horizontal = state.rankDir === "LR";
      const placed = new Set(cy.nodes().filter((n) => !nodes.has(n.id())).map((n) => n.id()));
      const boxes = () => cy.nodes().filter((n) => placed.has(n.id()) && !n.hasClass("hidden"));
      // The nodes' bodies: with labels and overlays each new first-layer node moved the edge
      // it is placed against by a few pixels.
      const BODIES = { includeLabels: false, includeOverlays: false, includeEdges: false };
      const main = (p) => horizontal ? p.x : p.y;
      const cross = (p) => horizontal ? p.y : p.x;
      const ext = (m) => (horizontal ? m.outerWidth() : m.outerHeight()) / 2;
      const place = (n) => {
        const preds = n.incomers("node").filter((m) => placed.has(m.id()));
        const succs = n.outgoers("node").filter((m) => placed.has(m.id()));
        let along, across;
        if (preds.length) {
          along = Math.max(...preds.map((m) => main(m.position()) + ext(m))) + RANK_GAP + ext(n);
          across = avg(preds.map((m) => cross(m.position())));
        } else if (succs.length) {
          along = Math.min(...succs.map((m) => main(m.position()) - ext(m))) - RANK_GAP - ext(n);
          across = avg(succs.map((m) => cross(m.position())));
        } else {
          // A new component: the first free place in the first layer, from the top (or
          // left) of the drawing, so that it takes the room a removed one left (below
          // everything, the drawing grew on every round of churn).
          const bb = boxes().boundingBox(BODIES);
          along = placed.size ? (horizontal ? bb.x1 : bb.y1) + ext(n) : 0;
          across = placed.size ? (horizontal ? bb.y1 + n.outerHeight() / 2 : bb.x1 + n.outerWidth() / 2) : 0;
        }
        const pos = (a, c) => horizontal ? { x: a, y: c } : { x: c, y: a };
        const others = boxes();
        let c = across;
        for (let i = 0; i < 500; i++) {
          const p = pos(along, c);
          const w = n.outerWidth() / 2 + NODE_GAP, h = n.outerHeight() / 2 + NODE_GAP;
          const hit = others.filter((m) => {
            const q = m.position();
            return Math.abs(q.x - p.x) < w + m.outerWidth() / 2 && Math.abs(q.y - p.y) < h + m.outerHeight() / 2;
          });
          if (!hit.length) break;
          c = horizontal ? Math.max(...hit.map((m) => m.position().y + m.outerHeight() / 2)) + NODE_GAP + n.outerHeight() / 2
                         : Math.max(...hit.map((m) => m.position().x + m.outerWidth() / 2)) + NODE_GAP + n.outerWidth() / 2;
        }
        n.position(pos(along, c));
        placed.add(n.id());
      };
      const touches = (n) => n.neighborhood("node").some((m) => placed.has(m.id()));
      let pending = [...nodes.values()];
      while (pending.length) {
        // Beside placed neighbours, for as long as that places any; then one new component
        // is seeded from a source of its own (a node nothing new feeds) and the rest follow
        // from it, so that its nodes are placed in the order of its edges.
        let progress = true;
        while (progress) {
          progress = false;
          const later = [];
          for (const n of pending) {
            if (touches(n)) { place(n); progress = true; } else later.push(n);
          }
          pending = later;
        }
        if (!pending.length) break;
        const seed = pending.reduce((best, n) =>
          n.incomers("node").length < best.incomers("node").length ? n : best);
        place(seed);
        pending = pending.filter((n) => n !== seed);
      }
    }

    function avg(xs) { return xs.reduce((a, b) => a + b, 0) / xs.length; }

    // Brings the graph to `view` ({cus, targets, crashed}): adds, removes and changes elements
    // in place. Returns the time it took (ms).
    function update(view) {
      const t0 = performance.now();
      const want = elements(view);
      const added = new Map();
      cy.batch(() => {
        cy.elements().forEach((el) => { if (!want.has(el.id())) el.remove(); });
        for (const [id, def] of want) {
          const el = cy.getElementById(id);
          if (el.nonempty()) {
            if (def.group === "edges" && (el.data("source") !== def.data.source || el.data("target") !== def.data.target)) {
              el.remove();
              cy.add(def);
              continue;
            }
            const d = el.data();
            for (const [k, v] of Object.entries(def.data)) if (!same(d[k], v)) el.data(k, v);
            if (def.classes !== undefined) el.classes(def.classes + (state.pinned.has(id) ? " pinned" : ""));
          } else {
            const created = cy.add(def);
            if (def.group === "nodes") added.set(id, created);
          }
        }
        applyFilters();
      });
      const nodes = cy.nodes().length;
      // Small graphs always show their labels; large ones drop those too small to read while
      // zoomed out (drawing thousands of tiny labels is what makes a big graph sluggish).
      const big = nodes > 150;
      if (big !== state.big) {
        state.big = big;
        cy.style().selector("node").style("min-zoomed-font-size", big ? 7 : 0).update();
      }
      if (!state.laidOut && nodes) {
        fullLayout(true);
      } else if (added.size && added.size > 0.5 * nodes && nodes > 4) {
        fullLayout(false);
      } else if (added.size) {
        placeNew(added);
        // Placing beside neighbours keeps what is drawn where it was, but churn leaves holes
        // that new components cannot always use: once the drawing is four times as sparse as a
        // fresh layout of it, it is laid out afresh.
        const now = spread();
        if (state.spread && now && now > 4 * state.spread) {
          state.metrics.relayouts = (state.metrics.relayouts || 0) + 1;
          fullLayout(false);
        }
      }
      const ms = performance.now() - t0;
      state.metrics.updates.push({ ms, nodes, added: added.size });
      if (state.metrics.updates.length > 500) state.metrics.updates.shift();
      return ms;
    }

    function same(a, b) {
      return a === b || JSON.stringify(a) === JSON.stringify(b);
    }

    function applyFilters() {
      cy.elements().removeClass("hidden");
      if (state.executor) {
        cy.nodes(".cu").filter((n) => n.data("executor") !== state.executor).addClass("hidden");
      }
      cy.nodes(".channel").forEach((ch) => {
        const visibleCu = ch.neighborhood("node.cu").filter((n) => !n.hasClass("hidden"));
        const idleHidden = state.hideIdle && ch.data("idle") && !ch.data("targets").length;
        const orphan = state.executor && !visibleCu.length && !ch.data("targets").length;
        if (idleHidden || orphan) ch.addClass("hidden");
      });
    }

    function flash(names) {
      const nodes = cy.collection();
      for (const n of names) nodes.merge(cy.getElementById("cu:" + n));
      nodes.addClass("flash");
      setTimeout(() => nodes.removeClass("flash"), 1500);
    }

    return {
      cy, update, flash,
      fit() { cy.fit(cy.elements(":visible"), 30); },
      relayout() { fullLayout(false); },
      setOrientation(dir) { state.rankDir = dir; fullLayout(false); },
      orientation() { return state.rankDir; },
      setExecutor(name) { state.executor = name; cy.batch(applyFilters); },
      setHideIdle(on) { state.hideIdle = on; cy.batch(applyFilters); },
      restyle() { cy.style(style()); cy.style().selector("node").style("min-zoomed-font-size", state.big ? 7 : 0).update(); },
      select(id) {
        const el = cy.getElementById(id);
        if (el.empty()) return false;
        cy.$(":selected").unselect();
        el.select();
        if (!el.renderedBoundingBox || !visible(el)) cy.center(el);
        return true;
      },
      positions() {
        const out = {};
        cy.nodes().forEach((n) => { out[n.id()] = Object.assign({}, n.position()); });
        return out;
      },
      metrics: state.metrics,
    };

    function visible(el) {
      const bb = el.renderedBoundingBox();
      return bb.x1 >= 0 && bb.y1 >= 0 && bb.x2 <= cy.width() && bb.y2 <= cy.height();
    }
  }

  window.DyGraph = { create, elements };
})();
