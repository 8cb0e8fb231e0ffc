// opendnc dashboard: the live cards' one script island (docs/dashboard.md#live-overview).
// The server sends one "cards" message per flush carrying every card that changed, each as
// an htmx out-of-band swap (<div id="card-NAME" hx-swap-oob="innerHTML">; on a machine page
// also the queue table's <span id="queue-progress-NAME">, so both show the same percent; an
// element the page does not have is skipped). htmx would do the
// swaps itself, but its per-element processing of ~200 cards at once blocked the page for
// over 100 ms; a card holds no htmx attributes, so plain DOM moves do the same work. Without
// this script htmx still swaps them.
//
// After each swap the page's own summaries follow the cards: the filters' counts, the list
// of machines in alarm, and an alert (the card flashes; a short beep if the person turned
// the sound on, remembered in this browser) when a machine goes into alarm. A card's
// glance (its shift's parts against the goal, today so far) is not the live part: it stays. Times say how
// long ago they were; the wall display (/wall) shows its pages in turn.
"use strict";

const opendnc = (window.opendnc = { beeps: 0, alerts: 0 });
const SOUND_KEY = "opendnc.alarmSound";
const known = new Map(); // machine -> the state its card showed last

function cardBodies() {
  return Array.from(document.querySelectorAll(".card-body[data-machine]"));
}

function updateCounts(bodies) {
  const counts = new Map();
  for (const body of bodies) counts.set(body.dataset.state, (counts.get(body.dataset.state) || 0) + 1);
  for (const el of document.querySelectorAll("[data-count]")) {
    const state = el.dataset.count;
    el.textContent = String(state === "all" ? bodies.length : counts.get(state) || 0);
  }
}

function updateAlarmList(bodies) {
  const banner = document.getElementById("alarm-banner");
  const list = document.getElementById("alarm-list");
  if (!banner || !list) return;
  const items = [];
  for (const body of bodies) {
    if (body.dataset.state !== "alarm") continue;
    const li = document.createElement("li");
    const link = document.createElement("a");
    link.href = "/machines/" + encodeURIComponent(body.dataset.machine);
    link.textContent = body.dataset.machine;
    li.append(link);
    const text = body.querySelector(".alarm-text");
    if (text) li.append(": " + text.textContent.replace(/^Alarm:\s*/, ""));
    items.push(li);
  }
  list.replaceChildren(...items);
  banner.hidden = items.length === 0;
}

let audio = null;
function soundOn() {
  try {
    return localStorage.getItem(SOUND_KEY) === "on";
  } catch (e) {
    return false; // storage refused (a locked-down browser): no sound
  }
}

function beep() {
  // Two short tones made here (no audio file): 880 Hz, 0.15 s each.
  const Context = window.AudioContext || window.webkitAudioContext;
  if (!Context) return;
  audio = audio || new Context();
  if (audio.state === "suspended") audio.resume();
  const start = audio.currentTime + 0.01;
  for (const offset of [0, 0.25]) {
    const osc = audio.createOscillator();
    const gain = audio.createGain();
    osc.type = "square";
    osc.frequency.value = 880;
    gain.gain.setValueAtTime(0.0001, start + offset);
    gain.gain.exponentialRampToValueAtTime(0.2, start + offset + 0.02);
    gain.gain.exponentialRampToValueAtTime(0.0001, start + offset + 0.15);
    osc.connect(gain).connect(audio.destination);
    osc.start(start + offset);
    osc.stop(start + offset + 0.16);
  }
  opendnc.beeps += 1;
}

function alertNewAlarms(bodies) {
  let fresh = false;
  for (const body of bodies) {
    const name = body.dataset.machine;
    const before = known.get(name);
    known.set(name, body.dataset.state);
    if (body.dataset.state === "alarm" && before !== undefined && before !== "alarm") {
      const card = body.closest(".card");
      if (card) {
        card.classList.remove("alarm-new");
        void card.offsetWidth; // restart the flash
        card.classList.add("alarm-new");
      }
      fresh = true;
    } else if (body.dataset.state !== "alarm") {
      const card = body.closest(".card");
      if (card) card.classList.remove("alarm-new");
    }
  }
  if (fresh) {
    opendnc.alerts += 1;
    if (soundOn()) beep();
  }
}

function ago(seconds) {
  if (seconds < 90) return "just now";
  const minutes = Math.round(seconds / 60);
  if (minutes < 90) return minutes + " min ago";
  const hours = Math.floor(minutes / 60);
  if (hours < 48) return hours + " h " + (minutes % 60) + " min ago";
  return Math.floor(hours / 24) + " days ago";
}

function updateAgo() {
  const now = Date.now();
  for (const time of document.querySelectorAll("time[data-ago]")) {
    const at = Date.parse(time.getAttribute("datetime"));
    const out = time.nextElementSibling;
    if (Number.isNaN(at) || !out || !out.classList.contains("ago")) continue;
    out.textContent = " · " + ago(Math.max(0, (now - at) / 1000));
  }
}

function refresh() {
  const bodies = cardBodies();
  alertNewAlarms(bodies);
  updateCounts(bodies);
  updateAlarmList(bodies);
  updateAgo();
  if (wall) wall.layout();
}

document.addEventListener("htmx:sseBeforeMessage", (event) => {
  const message = event.detail;
  if (!message || message.type !== "cards") return;
  event.preventDefault(); // swapped here, not by htmx
  const parsed = document.createElement("template");
  parsed.innerHTML = message.data;
  for (const part of Array.from(parsed.content.children)) {
    const card = document.getElementById(part.id);
    if (!card) continue;
    // the card's live part only: its glance (.glance, read every minute) stays
    const body = card.querySelector(":scope > .card-body");
    if (body && card.querySelector(":scope > .glance")) body.replaceWith(...part.childNodes);
    else card.replaceChildren(...part.childNodes);
  }
  refresh();
});

// -- the wall display: pages of cards shown in turn, a clock on the shop's zone ----------

class Wall {
  constructor(seconds) {
    this.seconds = seconds;
    this.index = 0;
    this.pages = [[]];
    this.signature = "";
  }

  layout() {
    // Lay every card out, then cut the rows that fit under the header into pages.
    const cards = Array.from(document.querySelectorAll(".cards > .card"));
    for (const card of cards) card.hidden = false;
    const list = document.querySelector(".cards");
    if (!list || cards.length === 0) return;
    const room = window.innerHeight - list.getBoundingClientRect().top - 8;
    const pages = [[]];
    let pageTop = null;
    for (const card of cards) {
      const box = card.getBoundingClientRect();
      if (pageTop === null) pageTop = box.top;
      if (box.bottom - pageTop > room && pages[pages.length - 1].length) {
        pages.push([]);
        pageTop = box.top;
      }
      pages[pages.length - 1].push(card);
    }
    this.pages = pages;
    if (this.index >= pages.length) this.index = 0;
    this.show();
  }

  show() {
    const shown = new Set(this.pages[this.index]);
    for (const page of this.pages) for (const card of page) card.hidden = !shown.has(card);
    const label = document.getElementById("wall-page");
    if (label) label.textContent = this.pages.length > 1 ? `page ${this.index + 1} of ${this.pages.length}` : "";
    document.body.dataset.wallPage = String(this.index + 1);
    document.body.dataset.wallPages = String(this.pages.length);
  }

  next() {
    this.index = (this.index + 1) % this.pages.length;
    this.layout();
  }
}

let wall = null;

function tickClock() {
  // The time on the shop's zone, named as every card names it ("CET", "CEST": the server's
  // word, from the page and then each heartbeat), not the browser's ("GMT+1").
  const clock = document.getElementById("wall-clock");
  if (!clock) return;
  const options = { hour: "2-digit", minute: "2-digit", hour12: false };
  const label = (window.opendncLive && window.opendncLive.zone) || document.body.dataset.zoneLabel || "";
  let text;
  try {
    options.timeZone = clock.dataset.zone;
    text = new Intl.DateTimeFormat("en-GB", options).format(new Date());
  } catch (e) {
    delete options.timeZone; // a zone this browser does not know: its own clock, named so
    options.timeZoneName = "short";
    clock.textContent = new Intl.DateTimeFormat("en-GB", options).format(new Date());
    return;
  }
  clock.textContent = label ? `${text} ${label}` : text;
}
document.addEventListener("opendnc:zone", tickClock);

document.addEventListener("DOMContentLoaded", () => {
  for (const body of cardBodies()) known.set(body.dataset.machine, body.dataset.state);
  const toggle = document.getElementById("alarm-sound");
  if (toggle) {
    toggle.checked = soundOn();
    toggle.addEventListener("change", () => {
      try {
        localStorage.setItem(SOUND_KEY, toggle.checked ? "on" : "off");
      } catch (e) {
        toggle.checked = false;
      }
      if (toggle.checked) {
        // made in the click: browsers let a page play sound only after a gesture
        const Context = window.AudioContext || window.webkitAudioContext;
        if (Context && !audio) audio = new Context();
      }
    });
  }
  const seconds = Number(document.body.dataset.wallSeconds || 0);
  if (seconds > 0) {
    wall = new Wall(seconds);
    wall.layout();
    setInterval(() => wall.next(), seconds * 1000);
    window.addEventListener("resize", () => wall.layout());
    tickClock();
    setInterval(tickClock, 10_000);
  }
  updateAgo();
  setInterval(updateAgo, 15_000);
});

// -- sending to many machines: "all machines" picks every box; the send asks first -------

document.addEventListener("change", (event) => {
  const box = event.target;
  if (!(box instanceof HTMLInputElement)) return;
  const form = box.form;
  if (!form) return;
  const name = box.dataset.pickAll;
  const boxes = (n) => Array.from(form.querySelectorAll(`input[type=checkbox][name="${n}"]`));
  if (name) {
    for (const each of boxes(name)) each.checked = box.checked;
    return;
  }
  const all = form.querySelector(`input[data-pick-all="${box.name}"]`);
  if (all) {
    const picked = boxes(box.name).filter((b) => b.checked).length;
    all.checked = picked === boxes(box.name).length;
    all.indeterminate = picked > 0 && !all.checked;
  }
});

document.addEventListener("htmx:confirm", (event) => {
  // A form marked data-confirm-many="N" asks before it sends to N machines or more, naming them.
  const form = event.detail.elt;
  if (!(form instanceof HTMLFormElement) || !form.dataset.confirmMany) return;
  const picked = Array.from(form.querySelectorAll('input[type=checkbox][name="machines"]:checked'));
  if (picked.length < Number(form.dataset.confirmMany)) return;
  event.preventDefault();
  const names = picked.map((b) => b.value);
  const shown = names.length > 8 ? names.slice(0, 8).join(", ") + ", …" : names.join(", ");
  if (window.confirm(`Send to ${names.length} machines (${shown})?`)) event.detail.issueRequest(true);
});
