// opendnc dashboard: the live cards' one script island (docs/dashboard.md#live-overview).
// The server sends one "cards" message per flush carrying every card that changed, each as
// an htmx out-of-band swap (<div id="card-NAME" hx-swap-oob="innerHTML">; on a machine page
// also the queue table's <span id="queue-progress-NAME">, so both show the same percent; an
// element the page does not have is skipped). htmx would do the
// swaps itself, but its per-element processing of ~200 cards at once blocked the page for
// over 100 ms; a card holds no htmx attributes, so plain DOM moves do the same work. Without
// this script htmx still swaps them.
document.addEventListener("htmx:sseBeforeMessage", (event) => {
  const message = event.detail;
  if (!message || message.type !== "cards") return;
  event.preventDefault(); // swapped here, not by htmx
  const parsed = document.createElement("template");
  parsed.innerHTML = message.data;
  for (const part of Array.from(parsed.content.children)) {
    const card = document.getElementById(part.id);
    if (card) card.replaceChildren(...part.childNodes);
  }
});
