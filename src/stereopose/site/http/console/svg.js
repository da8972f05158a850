// SVG elements for the console's drawings (the live plan, the Site tab, the surveyed points).

export const SVG = "http://www.w3.org/2000/svg";

/** An SVG element `name` with `attrs`, appended to `parent` when given. */
export function el(name, attrs = {}, parent = null) {
  const node = document.createElementNS(SVG, name);
  for (const [key, value] of Object.entries(attrs)) node.setAttribute(key, String(value));
  if (parent) parent.appendChild(node);
  return node;
}
