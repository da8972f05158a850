// HTML elements for the console's panels: text always goes in as text, never as markup.

/** A `tag` element holding `content` as text, of class `className` when given. */
export function text(tag, content = "", className = "") {
  const node = document.createElement(tag);
  node.textContent = content;
  if (className) node.className = className;
  return node;
}
