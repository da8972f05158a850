// HTML elements for the consoles' panels (the site's and the control room's): text always goes
// in as text, never as markup.

/** The page's element of id `id` (null when none). */
export const byId = (id) => document.getElementById(id);

/** A `tag` element holding `content` as text, of class `className` when given. */
export function text(tag, content = "", className = "") {
  const node = document.createElement(tag);
  node.textContent = content;
  if (className) node.className = className;
  return node;
}
