// Results tables in reports (evalkit/pages.py, results_table_html): a click on a column's name
// sorts the rows by it (a second click, the other way); a click on a group's name (settings,
// bundle metrics, image metrics, timings) hides its columns or shows them again.
"use strict";

document.addEventListener("DOMContentLoaded", () => {
  document.querySelectorAll("table.ek-table").forEach((table) => {
    const body = table.tBodies[0];
    const value = (row, col) => {
      const text = row.cells[col].textContent;
      const number = Number(text);
      return text !== "-" && text !== "" && !Number.isNaN(number) ? number : text;
    };
    table.querySelectorAll("tr.ek-columns th").forEach((th) => {
      th.addEventListener("click", () => {
        const col = th.cellIndex;
        const sign = th.dataset.sort === "ascending" ? -1 : 1;
        table.querySelectorAll("tr.ek-columns th").forEach((other) => delete other.dataset.sort);
        th.dataset.sort = sign === 1 ? "ascending" : "descending";
        const rows = [...body.rows];
        rows.sort((a, b) => {
          const x = value(a, col);
          const y = value(b, col);
          if (typeof x !== typeof y) return (typeof x === "number" ? -1 : 1) * sign; // numbers first
          return (x < y ? -1 : x > y ? 1 : 0) * sign;
        });
        rows.forEach((row) => body.appendChild(row));
      });
    });
    table.querySelectorAll("tr.ek-groups th").forEach((th) => {
      th.addEventListener("click", () => {
        const hidden = table.classList.toggle(`ek-hide-${th.dataset.group}`);
        th.colSpan = hidden ? 1 : Number(th.dataset.span);
        th.title = hidden ? "show these columns" : "hide these columns";
      });
    });
  });
});
