// SVG elements for the console's drawings (the live plan, the Site tab, the surveyed points).

export const SVG = "http://www.w3.org/2000/svg";

/** An SVG element `name` with `attrs`, appended to `parent` when given. */
export function el(name, attrs = {}, parent = null) {
  const node = document.createElementNS(SVG, name);
  for (const [key, value] of Object.entries(attrs)) node.setAttribute(key, String(value));
  if (parent) parent.appendChild(node);
  return node;
}

/** The box of an SVG element in its own user units; null where it is not laid out. */
function boxOf(node) {
  try {
    const b = node.getBBox();
    return b.width > 0 && b.height > 0 ? { x: b.x, y: b.y, width: b.width, height: b.height } : null;
  } catch {
    return null; // not rendered (its tab hidden)
  }
}

const meets = (a, b) =>
  a.x < b.x + b.width && b.x < a.x + a.width && a.y < b.y + b.height && b.y < a.y + a.height;

/** Text labels (in one coordinate system, placed where they belong) moved apart where they
 * would overlap: from the top down, each that meets one already placed goes just below it
 * (gap between), and a leader line (class "leader", in the label's parent) ties it to where it
 * belonged; a label not moved hides its line. */
export function separateLabels(labels, gap = 0) {
  const items = labels
    .map((text) => ({ text, box: boxOf(text), y: Number(text.getAttribute("y")) }))
    .filter((item) => item.box && Number.isFinite(item.y))
    .sort((a, b) => a.box.y - b.box.y || a.box.x - b.box.x);
  const placed = [];
  for (const item of items) {
    const box = { ...item.box };
    for (let tries = 0; tries < 4 * items.length; tries += 1) {
      const hit = placed.find((other) => meets(other, box));
      if (!hit) break;
      box.y = hit.y + hit.height + gap;
    }
    const moved = box.y - item.box.y;
    item.text.setAttribute("y", (item.y + moved).toFixed(3));
    placed.push(box);
    const parent = item.text.parentNode;
    let leader = parent && parent.querySelector(":scope > line.leader");
    if (moved > 0 && parent) {
      if (!leader) leader = el("line", { class: "leader" }, parent);
      const x = Number(item.text.getAttribute("x"));
      leader.setAttribute("x1", x.toFixed(3));
      leader.setAttribute("y1", item.box.y.toFixed(3));
      leader.setAttribute("x2", x.toFixed(3));
      leader.setAttribute("y2", box.y.toFixed(3));
      leader.removeAttribute("visibility");
    } else if (leader) {
      leader.setAttribute("visibility", "hidden");
    }
  }
}
