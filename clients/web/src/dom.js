// The one helper every page uses to build its elements.

export function el(tag, attributes = {}, ...children) {
  const node = document.createElement(tag);
  for (const [key, value] of Object.entries(attributes)) {
    if (key === "class") node.className = value;
    else if (key.startsWith("on")) node.addEventListener(key.slice(2), value);
    else if (key === "dataset") Object.assign(node.dataset, value);
    else node.setAttribute(key, value);
  }
  node.append(...children.filter((c) => c !== null && c !== undefined));
  return node;
}

// A file's size for people: B, kB or MB.
export function sizeText(bytes) {
  if (bytes < 1024) return `${bytes} B`;
  if (bytes < 1024 ** 2) return `${(bytes / 1024).toFixed(1)} kB`;
  return `${(bytes / 1024 ** 2).toFixed(1)} MB`;
}

// A job's or run's status as shown: a succeeded one with a warning (seams a measurement
// left unmeasured) reads "succeeded · warning", never a plain success.
export function statusNode(item, attributes = {}) {
  const warned = item.status === "succeeded" && item.warning;
  return el(
    "span",
    { ...attributes, class: warned ? "status-warning" : `status-${item.status}`, title: warned ? item.warning : "" },
    warned ? "succeeded · warning" : item.status,
  );
}
