// helicalib crew console: swaps in the panels the server sends on /stream (server-sent events),
// filters the event log, and posts operator actions. No external resource: the plant LAN has no internet.
(function () {
  "use strict";
  var updates = 0;
  var conn = document.getElementById("connection");

  function filterEvents() {
    var kind = document.getElementById("event-kind").value;
    var text = document.getElementById("event-text").value.toLowerCase();
    document.querySelectorAll("#events tbody tr").forEach(function (tr) {
      var show = (!kind || tr.dataset.kind === kind) && (!text || tr.textContent.toLowerCase().indexOf(text) >= 0);
      tr.classList.toggle("hidden", !show);
    });
  }

  function refreshKinds() {  // the kind filter lists every kind in the log, keeping the choice
    var select = document.getElementById("event-kind");
    var have = {};
    Array.prototype.forEach.call(select.options, function (o) { have[o.value] = true; });
    document.querySelectorAll("#events tbody tr").forEach(function (tr) {
      var k = tr.dataset.kind;
      if (k && !have[k]) {
        var o = document.createElement("option");
        o.value = k; o.textContent = k; select.appendChild(o); have[k] = true;
      }
    });
  }

  function apply(panels) {
    Object.keys(panels).forEach(function (name) {
      if (name === "actions" && document.activeElement && document.activeElement.closest &&
          document.activeElement.closest("#action-form")) {
        var holder = document.createElement("div");  // keep what the operator is typing: the list only
        holder.innerHTML = panels[name];
        var list = document.getElementById("actions-list"), fresh = holder.querySelector("#actions-list");
        if (list && fresh) { list.innerHTML = fresh.innerHTML; }
        return;
      }
      var el = document.getElementById("panel-" + name);
      if (!el) { return; }
      if (name === "actions") {
        var who = document.getElementById("action-who"), hs = document.getElementById("action-heliostats");
        var result = document.getElementById("action-result");
        var keep = [who ? who.value : "", hs ? hs.value : "", result ? result.textContent : ""];
        el.innerHTML = panels[name];
        wireActions();
        if (document.getElementById("action-who")) {
          document.getElementById("action-who").value = keep[0];
          document.getElementById("action-heliostats").value = keep[1];
          document.getElementById("action-result").textContent = keep[2];
        }
      } else {
        el.innerHTML = panels[name];
      }
    });
    refreshKinds();
    filterEvents();
    if (panels.map) { drawMap(); }
    if (Date.now() - table.loadedAt > 5000) { loadTable(); }  // the table follows the campaign, gently
    updates += 1;
    document.body.dataset.updates = String(updates);
  }

  // ---- the field map on a canvas (large fields): positions drawn into the page once, states in
  // the map panel's data-codes (one letter per heliostat), redrawn whenever the panel is swapped
  var COLORS = {w: "#bbb", o: "#1f77b4", a: "#2a9d3a", r: "#d1495b", t: "#e59f00"};
  var STATE_NAMES = {w: "waiting", o: "on a board", a: "accepted", r: "refused or out of service", t: "needs attention"};
  var positions = null;

  function mapPositions() {
    if (positions === null) {
      var el = document.getElementById("map-positions");
      positions = el ? JSON.parse(el.textContent) : {ids: [], x: [], y: []};
    }
    return positions;
  }

  function nearest(canvas, event) {
    var pos = mapPositions(), rect = canvas.getBoundingClientRect();
    var sx = canvas.width / rect.width, sy = canvas.height / rect.height;
    var x = (event.clientX - rect.left) * sx, y = (event.clientY - rect.top) * sy;
    var best = -1, bestD = Math.pow(Math.max(4, 2 * Number(canvas.dataset.r)), 2);
    for (var i = 0; i < pos.ids.length; i++) {
      if (pos.x[i] === null) { continue; }
      var d = (pos.x[i] - x) * (pos.x[i] - x) + (pos.y[i] - y) * (pos.y[i] - y);
      if (d < bestD) { bestD = d; best = i; }
    }
    return best;
  }

  function drawMap() {
    var canvas = document.getElementById("field-canvas");
    if (!canvas) { return; }
    var pos = mapPositions(), codes = canvas.dataset.codes || "", r = Number(canvas.dataset.r) || 2;
    var ctx = canvas.getContext("2d"), drawn = 0;
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    var tower = (canvas.dataset.tower || "").split(",").map(Number);
    if (tower.length === 2) { ctx.fillStyle = "#444"; ctx.fillRect(tower[0] - 6, tower[1] - 6, 12, 12); }
    Object.keys(COLORS).forEach(function (code) {  // one path per state: 10^4 dots in a few ms
      ctx.beginPath();
      for (var i = 0; i < pos.ids.length; i++) {
        if (codes.charAt(i) !== code || pos.x[i] === null) { continue; }
        ctx.moveTo(pos.x[i] + r, pos.y[i]);
        ctx.arc(pos.x[i], pos.y[i], r, 0, 2 * Math.PI);
        drawn += 1;
      }
      ctx.fillStyle = COLORS[code];
      ctx.fill();
    });
    canvas.dataset.drawn = String(drawn);
    if (!window.helicalibMapDrawnAt) { window.helicalibMapDrawnAt = performance.now(); }
    canvas.addEventListener("mousemove", function (event) {
      var i = nearest(canvas, event), hover = document.getElementById("field-hover");
      if (hover) {
        hover.textContent = i < 0 ? "Point at a heliostat for its id; click it for its sheet." :
          pos.ids[i] + ": " + (STATE_NAMES[codes.charAt(i)] || "");
      }
    });
    canvas.addEventListener("click", function (event) {
      var i = nearest(canvas, event);
      if (i >= 0) { window.location.href = "/heliostat/" + encodeURIComponent(pos.ids[i]); }
    });
  }

  // ---- the heliostats table: one page at a time from /api/heliostats, filtered and sorted there
  var table = {sort: "block", order: "asc", offset: 0, limit: 50, total: 0, matched: 0, loadedAt: 0, seq: 0};

  function cell(tr, text, num) {
    var td = document.createElement("td");
    td.textContent = text === null || text === undefined ? "—" : String(text);
    if (num) { td.className = "num"; }
    tr.appendChild(td);
    return td;
  }

  function tableQuery() {
    var params = new URLSearchParams();
    [["board", "hel-board"], ["verdict", "hel-verdict"], ["state", "hel-state"], ["q", "hel-q"],
     ["min_error", "hel-min-error"], ["max_error", "hel-max-error"]].forEach(function (pair) {
      var el = document.getElementById(pair[1]);
      if (el && el.value !== "") { params.set(pair[0], el.value); }
    });
    params.set("sort", table.sort); params.set("order", table.order);
    params.set("offset", String(table.offset)); params.set("limit", String(table.limit));
    return params.toString();
  }

  function loadTable() {
    var body = document.getElementById("hel-rows"), info = document.getElementById("hel-info");
    if (!body) { return; }
    var seq = ++table.seq;
    table.loadedAt = Date.now();
    fetch("/api/heliostats?" + tableQuery(), {credentials: "same-origin"})
      .then(function (r) { return r.json().then(function (j) { return [r.ok, j]; }); })
      .then(function (res) {
        if (seq !== table.seq) { return; }  // a newer request is on its way
        if (!res[0]) { info.textContent = "refused: " + res[1].error; return; }
        var page = res[1];
        table.total = page.total; table.matched = page.matched;
        var fresh = document.createDocumentFragment();
        page.rows.forEach(function (row) {
          var tr = document.createElement("tr");
          tr.dataset.id = row.heliostat_id;
          var a = document.createElement("a");
          a.href = "/heliostat/" + encodeURIComponent(row.heliostat_id);
          a.textContent = row.heliostat_id;
          cell(tr, "").appendChild(a);
          cell(tr, row.target_id); cell(tr, row.state); cell(tr, row.verdict);
          cell(tr, row.visits, true); cell(tr, row.valid, true);
          cell(tr, row.last_error_mrad === null ? null : row.last_error_mrad.toFixed(2), true);
          cell(tr, row.rms_mrad === null ? null : row.rms_mrad.toFixed(2), true);
          cell(tr, row.missing);
          fresh.appendChild(tr);
        });
        body.innerHTML = "";
        body.appendChild(fresh);
        var first = page.matched ? page.offset + 1 : 0, last = Math.min(page.offset + page.limit, page.matched);
        info.textContent = "rows " + first + "–" + last + " of " + page.matched + " matching (" + page.total +
          " heliostats)";
        info.dataset.matched = String(page.matched); info.dataset.total = String(page.total);
        info.dataset.offset = String(page.offset);
        document.querySelectorAll("table.hel-table th[data-sort]").forEach(function (th) {
          th.classList.toggle("sorted-asc", th.dataset.sort === page.sort && page.order === "asc");
          th.classList.toggle("sorted-desc", th.dataset.sort === page.sort && page.order === "desc");
        });
        document.body.dataset.tableLoads = String(Number(document.body.dataset.tableLoads || 0) + 1);
        if (!window.helicalibTableLoadedAt) { window.helicalibTableLoadedAt = performance.now(); }
      })
      .catch(function (err) { info.textContent = "not loaded: " + err; });
  }

  function wireTable() {
    if (!document.getElementById("hel-rows")) { return; }
    var timer = null;
    function again() { table.offset = 0; loadTable(); }
    ["hel-board", "hel-verdict", "hel-state"].forEach(function (id) {
      document.getElementById(id).addEventListener("change", again);
    });
    ["hel-q", "hel-min-error", "hel-max-error"].forEach(function (id) {
      document.getElementById(id).addEventListener("input", function () {
        clearTimeout(timer); timer = setTimeout(again, 250);
      });
    });
    document.querySelectorAll("table.hel-table th[data-sort]").forEach(function (th) {
      th.addEventListener("click", function () {
        table.order = table.sort === th.dataset.sort && table.order === "asc" ? "desc" : "asc";
        table.sort = th.dataset.sort;
        again();
      });
    });
    document.getElementById("hel-prev").addEventListener("click", function () {
      table.offset = Math.max(0, table.offset - table.limit); loadTable();
    });
    document.getElementById("hel-next").addEventListener("click", function () {
      if (table.offset + table.limit < table.matched) { table.offset += table.limit; loadTable(); }
    });
    loadTable();
  }

  function connect() {
    var source = new EventSource("/stream");
    source.onopen = function () { conn.textContent = "live"; conn.className = "conn ok"; };
    source.onerror = function () { conn.textContent = "connection lost: retrying"; conn.className = "conn lost"; };
    source.onmessage = function (msg) {
      var data = JSON.parse(msg.data);
      if (data.panels) { apply(data.panels); }
    };
  }

  function wireActions() {
    var form = document.getElementById("action-form");
    if (!form) { return; }
    form.querySelectorAll("button[data-kind]").forEach(function (button) {
      button.addEventListener("click", function () {
        var result = document.getElementById("action-result");
        var kind = button.dataset.kind;
        var ids = document.getElementById("action-heliostats").value;
        var body = {kind: kind, who: document.getElementById("action-who").value,
                    heliostats: (kind === "pause" || kind === "resume") ? [] :
                      ids.split(",").map(function (s) { return s.trim(); }).filter(Boolean)};
        result.textContent = "sending " + kind + "…";
        fetch("/api/action", {method: "POST", headers: {"Content-Type": "application/json"},
                              body: JSON.stringify(body), credentials: "same-origin"})
          .then(function (r) { return r.json().then(function (j) { return [r.ok, j]; }); })
          .then(function (res) {
            result.textContent = res[0] ? ("action " + res[1].id + " (" + res[1].kind + ") " + res[1].status)
                                        : ("refused: " + res[1].error);
          })
          .catch(function (err) { result.textContent = "not sent: " + err; });
      });
    });
  }

  document.getElementById("event-kind").addEventListener("change", filterEvents);
  document.getElementById("event-text").addEventListener("input", filterEvents);
  wireActions();
  drawMap();
  wireTable();
  window.helicalibConsoleLoadedAt = Date.now();
  connect();
}());
