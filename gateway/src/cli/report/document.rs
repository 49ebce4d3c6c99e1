//! The report's document model ([`Block`]) and its two renderings: Markdown with the
//! plots linked ([`markdown`]) and one offline HTML page with the plots inline
//! ([`html`]).

use std::fmt::Write as _;

use crate::outputs::web::page::escape;

/// One part of the report.
#[derive(Debug, Clone, PartialEq)]
pub enum Block {
    /// A heading of level 1..=3.
    Heading(u8, String),
    /// A paragraph.
    Text(String),
    /// A table: header and rows.
    Table(Vec<String>, Vec<Vec<String>>),
    /// A plot: its file name, its title and the SVG document.
    Figure {
        /// File name in the report folder.
        file: String,
        /// What it shows.
        title: String,
        /// The SVG.
        svg: String,
    },
}

/// A table cell of `value` with `digits` decimals, `-` for none.
pub(super) fn fmt(value: Option<f64>, digits: usize) -> String {
    value.map_or_else(|| "-".to_owned(), |v| format!("{v:.digits$}"))
}

/// The report as Markdown, figures linked to their files.
pub fn markdown(blocks: &[Block]) -> String {
    let mut out = String::new();
    for block in blocks {
        match block {
            Block::Heading(level, text) => {
                let _ = writeln!(out, "{} {text}\n", "#".repeat(usize::from(*level)));
            }
            Block::Text(text) => {
                let _ = writeln!(out, "{text}\n");
            }
            Block::Table(header, rows) => {
                let _ = writeln!(out, "| {} |", header.join(" | "));
                let _ = writeln!(out, "|{}", "---|".repeat(header.len()));
                for row in rows {
                    let cells: Vec<String> = row.iter().map(|c| c.replace('|', "\\|")).collect();
                    let _ = writeln!(out, "| {} |", cells.join(" | "));
                }
                out.push('\n');
            }
            Block::Figure { file, title, .. } => {
                let _ = writeln!(out, "![{title}]({file})\n");
            }
        }
    }
    out
}

/// The report as one HTML page that needs no other file: the SVGs are inline. Every
/// part of it is in a landmark (what axe's `region` and `landmark-one-main` rules
/// ask): the first heading in `<header>`, a `<nav>` of links to the sections (the
/// level-2 headings), the rest in `<main>`.
pub fn html(title: &str, blocks: &[Block]) -> String {
    let mut out = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\
         <title>{}</title>\n\
         <style>body{{font-family:sans-serif;max-width:960px;margin:2em auto;padding:0 8px;\
         color:#222}}h1,h2,h3,p,figcaption{{overflow-wrap:anywhere}}\
         .scroll{{overflow-x:auto}}table{{border-collapse:collapse;margin:1em 0}}\
         td,th{{border:1px solid #bbb;padding:2px 8px;text-align:left}}figure{{margin:1em 0}}\
         svg{{max-width:100%;height:auto}}nav ul{{padding-left:1.2em}}</style></head><body>\n",
        escape(title)
    );
    let blocks = match blocks.split_first() {
        Some((Block::Heading(1, heading), rest)) => {
            let _ = writeln!(out, "<header><h1>{}</h1></header>", escape(heading));
            rest
        }
        _ => blocks,
    };
    let sections: Vec<&String> = blocks
        .iter()
        .filter_map(|block| match block {
            Block::Heading(2, text) => Some(text),
            _ => None,
        })
        .collect();
    if !sections.is_empty() {
        out.push_str("<nav aria-label=\"Sections\"><ul>\n");
        for (index, text) in sections.iter().enumerate() {
            let _ = writeln!(
                out,
                "<li><a href=\"#section-{}\">{}</a></li>",
                index + 1,
                escape(text)
            );
        }
        out.push_str("</ul></nav>\n");
    }
    out.push_str("<main>\n");
    let mut section = 0;
    for block in blocks {
        match block {
            Block::Heading(2, text) => {
                section += 1;
                let _ = writeln!(out, "<h2 id=\"section-{section}\">{}</h2>", escape(text));
            }
            Block::Heading(level, text) => {
                let _ = writeln!(out, "<h{level}>{}</h{level}>", escape(text));
            }
            Block::Text(text) => {
                let _ = writeln!(out, "<p>{}</p>", escape(text));
            }
            Block::Table(header, rows) => {
                // A table wider than a phone scrolls in its own box.
                out.push_str("<div class=\"scroll\" tabindex=\"0\"><table><tr>");
                for cell in header {
                    let _ = write!(out, "<th>{}</th>", escape(cell));
                }
                out.push_str("</tr>\n");
                for row in rows {
                    out.push_str("<tr>");
                    for cell in row {
                        let _ = write!(out, "<td>{}</td>", escape(cell));
                    }
                    out.push_str("</tr>\n");
                }
                out.push_str("</table></div>\n");
            }
            Block::Figure { title, svg, .. } => {
                // The SVG document without its XML declaration, inline.
                let body = svg.find("<svg").map_or(svg.as_str(), |at| &svg[at..]);
                let _ = writeln!(
                    out,
                    "<figure>{body}<figcaption>{}</figcaption></figure>",
                    escape(title)
                );
            }
        }
    }
    out.push_str("</main>\n</body></html>\n");
    out
}
