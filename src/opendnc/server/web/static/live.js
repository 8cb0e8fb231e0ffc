// opendnc dashboard: is what the page shows live? (docs/dashboard.md#live-overview)
// A page kept up to date by server-sent events hears from the server at least every 2 s (a
// "heartbeat" event with the server's time and the shop's zone label). When the browser
// reports the stream broken (a server that stopped closes it) or 5 s pass without a word (a
// server or a network gone silent), the page greys and a banner says since when; the htmx
// SSE extension reconnects by itself, and the first word from the server makes it live again
// (the stream opens with a fresh copy of what the page shows).
"use strict";

(() => {
  const SILENT_MS = 5000;
  const live = (window.opendncLive = { heard: Date.now(), lost: null, zone: "", opened: 0 });

  function shopClock(at) {
    const zone = document.body.dataset.zone;
    const options = { hour: "2-digit", minute: "2-digit", second: "2-digit", hour12: false };
    try {
      if (zone) options.timeZone = zone;
      return new Intl.DateTimeFormat("en-GB", options).format(at);
    } catch (e) {
      delete options.timeZone; // a zone this browser does not know: its own clock
      return new Intl.DateTimeFormat("en-GB", options).format(at);
    }
  }

  function streaming() {
    return document.querySelector("[sse-connect]") !== null;
  }

  function lose() {
    if (live.lost !== null || !streaming()) return;
    live.lost = new Date(live.heard);
    const banner = document.getElementById("stale");
    if (banner) {
      const label = live.zone || document.body.dataset.zoneLabel || "";
      const since = shopClock(live.lost) + (label ? " " + label : "");
      banner.textContent =
        `No connection to the server since ${since}: what this page shows may be out of date. Reconnecting…`;
      banner.hidden = false;
    }
    document.documentElement.classList.add("stale");
  }

  function heard() {
    live.heard = Date.now();
    if (live.lost === null) return;
    live.lost = null;
    const banner = document.getElementById("stale");
    if (banner) banner.hidden = true;
    document.documentElement.classList.remove("stale");
  }

  function beat(event) {
    try {
      const data = JSON.parse(event.data);
      if (data.zone) {
        live.zone = data.zone;
        document.dispatchEvent(new CustomEvent("opendnc:zone", { detail: data.zone }));
      }
    } catch (e) {
      // an unreadable heartbeat still says the server is there
    }
    heard();
  }

  document.addEventListener("htmx:sseOpen", (event) => {
    const source = event.detail && event.detail.source;
    if (source && !source.opendncHeartbeat) {
      source.opendncHeartbeat = true;
      source.addEventListener("heartbeat", beat);
      live.opened += 1;
    }
  });
  document.addEventListener("htmx:sseMessage", heard);
  // A broken stream greys the page unless the reconnection is heard from at once: a stream
  // the server ends on purpose (one idle for [clients] stream_idle) comes straight back.
  document.addEventListener("htmx:sseError", () => {
    const at = Date.now();
    setTimeout(() => {
      if (live.heard < at) lose();
    }, 1500);
  });
  setInterval(() => {
    if (Date.now() - live.heard > SILENT_MS) lose();
  }, 500);
})();
