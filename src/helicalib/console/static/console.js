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
    updates += 1;
    document.body.dataset.updates = String(updates);
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
  window.helicalibConsoleLoadedAt = Date.now();
  connect();
}());
