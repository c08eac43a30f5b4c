"""The report page's style sheet: one column at most 1120 px wide on a screen; printed on A4, every figure
kept whole on a page and every picture within the page's width."""

STYLE = """
:root { --ink: #1d2733; --muted: #5b6775; --rule: #d5dbe2; --accent: #c0392b; }
* { box-sizing: border-box; }
body { font: 14px/1.45 system-ui, -apple-system, "Segoe UI", Roboto, "DejaVu Sans", sans-serif;
       color: var(--ink); background: #ffffff; max-width: 1120px; margin: 0 auto; padding: 16px 24px 48px; }
header { border-bottom: 2px solid var(--ink); margin-bottom: 12px; }
h1 { font-size: 22px; margin: 0 0 2px; }
h3 { font-size: 16px; margin: 0 0 8px; }
h4 { font-size: 13px; margin: 12px 0 4px; text-transform: uppercase; letter-spacing: 0.04em;
     color: var(--muted); }
.subtitle { color: var(--muted); margin: 0 0 8px; font-size: 12px; }
figure { margin: 0 0 18px; padding: 12px 0 14px; border-bottom: 1px solid var(--rule);
         break-inside: avoid; page-break-inside: avoid; }
figcaption { color: var(--muted); font-size: 12.5px; margin-top: 8px; max-width: 880px; }
img { display: block; max-width: 100%; height: auto; }
img.plot { width: 640px; }
img.plot.square { width: 460px; }
img.wide { width: 100%; }
img.bar { width: 100%; height: auto; margin-top: 4px; }
.tables { display: grid; grid-template-columns: 3fr 2fr; gap: 16px; align-items: start; }
table.result { border-collapse: collapse; width: 100%; font-size: 13px; }
table.result th, table.result td { text-align: left; padding: 3px 8px; border-bottom: 1px solid var(--rule);
                                   vertical-align: top; }
table.result th { font-weight: 600; color: var(--muted); }
table[data-table="cameras"] tr:first-child th { color: var(--ink); }
table[data-table="frames"] { max-width: 720px; }
.num { font-variant-numeric: tabular-nums; }
.held { color: var(--accent); font-size: 12px; }
.note { color: var(--muted); font-size: 12px; }
ul.warnings li { color: #9a4d00; }
ul { margin: 2px 0 4px; padding-left: 20px; }
p.none { margin: 2px 0; color: var(--muted); }
.fields { display: grid; grid-template-columns: 2fr 1fr 1fr; gap: 8px; margin-bottom: 12px; }
.fields .main { grid-row: span 2; }
.fields.plain { grid-template-columns: 1fr; }
.pair { display: grid; grid-template-columns: 1fr 1fr; gap: 10px; }
.panel .label { font-size: 11.5px; color: var(--muted); margin-top: 3px; }
.panel img { width: 100%; }
.scale .ticks { display: flex; justify-content: space-between; font-size: 10.5px; color: var(--muted); }
p.numbers { font-size: 12.5px; margin: 4px 0 0; }
@page { size: A4; margin: 12mm; }
@media print {
  body { max-width: none; padding: 0; font-size: 11px; }
  * { -webkit-print-color-adjust: exact; print-color-adjust: exact; }
  figure { break-inside: avoid; page-break-inside: avoid; }
  img.plot { width: 150mm; }
  img.plot.square { width: 105mm; }
  .tables { grid-template-columns: 1fr 1fr; }
}
"""
