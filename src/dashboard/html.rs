//! Small HTML helpers: escaping, the page layout, tables, figures with view controls, forms.

use std::fmt::Write;

use axum::http::StatusCode;
use axum::response::{Html, IntoResponse, Response};

/// Why a page could not be shown: a use case's error, rendered as a readable HTML page with
/// its status (the API renders the same errors as problem+json; this edge has its own face).
#[derive(Debug)]
pub struct PageError(pub crate::service::Error);

impl PageError {
    pub fn internal(cause: impl Into<anyhow::Error>) -> Self {
        PageError(crate::service::Error::internal(cause))
    }
}

impl<E: Into<crate::service::Error>> From<E> for PageError {
    fn from(e: E) -> Self {
        PageError(e.into())
    }
}

impl IntoResponse for PageError {
    fn into_response(self) -> Response {
        use crate::service::Error as E;
        let status = match &self.0 {
            E::Invalid(_) | E::Payload(_) => StatusCode::UNPROCESSABLE_ENTITY,
            E::NotFound { .. } => StatusCode::NOT_FOUND,
            E::Conflict(_) => StatusCode::CONFLICT,
            E::NotReady { .. } | E::Unavailable(_) => StatusCode::SERVICE_UNAVAILABLE,
            _ => StatusCode::INTERNAL_SERVER_ERROR,
        };
        // Internal causes are logged, never shown.
        let text = if status == StatusCode::INTERNAL_SERVER_ERROR {
            tracing::error!(error = ?self.0, "dashboard page failed");
            "internal error; see the server logs".to_owned()
        } else {
            self.0.to_string()
        };
        let body = format!(
            "<section class=\"notfound\"><p>{}</p><p><a href=\"/\">Overview</a></p></section>",
            esc(&text)
        );
        (status, Html(page("Error", "/", &body))).into_response()
    }
}

/// Escapes text for HTML element content and quoted attribute values (`&<>"'`).
pub fn esc(s: &str) -> String {
    html_escape::encode_quoted_attribute(s).into_owned()
}

/// The sections of the navigation bar: (path, label).
pub const NAV: [(&str, &str); 12] = [
    ("/", "Overview"),
    ("/ui/plans", "Plans"),
    ("/ui/robots", "Robots"),
    ("/ui/objects", "Objects"),
    ("/ui/demonstrations", "Demonstrations"),
    ("/ui/mappings", "Mappings"),
    ("/ui/models", "Models"),
    ("/ui/grasps", "Grasps"),
    ("/ui/trajectories", "Trajectories"),
    ("/ui/bridges", "Bridges"),
    ("/ui/executions", "Executions"),
    ("/ui/jobs", "Jobs"),
];

/// A complete page.
pub fn page(title: &str, active: &str, body: &str) -> String {
    let mut nav = String::new();
    for (href, label) in NAV {
        let class = if href == active {
            " class=\"active\""
        } else {
            ""
        };
        let _ = write!(nav, "<a href=\"{href}\"{class}>{label}</a>");
    }
    format!(
        "<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\
         <title>{t} · reachgrasp</title>\
         <link rel=\"stylesheet\" href=\"/assets/style.css\">\
         <script src=\"/assets/app.js\" defer></script></head>\
         <body><header><a class=\"brand\" href=\"/\">reachgrasp</a><nav>{nav}</nav>\
         <a class=\"docs\" href=\"/docs\">API docs</a></header>\
         <main><h1>{t}</h1>\n{body}\n</main></body></html>",
        t = esc(title),
    )
}

/// A 200 HTML page.
pub fn ok(title: &str, active: &str, body: &str) -> Response {
    Html(page(title, active, body)).into_response()
}

/// A readable not-found page (status 404, HTML).
pub fn not_found(what: &str, id: &str, list_href: &str, list_label: &str) -> Response {
    let body = format!(
        "<section class=\"notfound\"><p>There is no {w} with id <code>{i}</code>. It may have \
         been deleted, or the link is mistyped.</p><p><a href=\"{list_href}\">All {list_label}</a>\
         </p></section>",
        w = esc(what),
        i = esc(id),
    );
    (
        StatusCode::NOT_FOUND,
        Html(page(&format!("{what} not found"), list_href, &body)),
    )
        .into_response()
}

/// A page for a dashboard path that does not exist (a browser gets HTML, not problem+json).
pub fn no_such_page(path: &str) -> Response {
    let body = format!(
        "<section class=\"notfound\"><p>There is no page at <code>{}</code>; the link may be \
         mistyped.</p><p><a href=\"/\">Overview</a></p></section>",
        esc(path)
    );
    (
        StatusCode::NOT_FOUND,
        Html(page("Page not found", "/", &body)),
    )
        .into_response()
}

/// An HTML table; cells are already HTML.
pub fn table(headers: &[&str], rows: &[Vec<String>]) -> String {
    if rows.is_empty() {
        return "<p class=\"empty\">Nothing here yet.</p>".into();
    }
    let mut s = String::from("<table><thead><tr>");
    for h in headers {
        let _ = write!(s, "<th>{}</th>", esc(h));
    }
    s.push_str("</tr></thead><tbody>");
    for r in rows {
        s.push_str("<tr>");
        for c in r {
            let _ = write!(s, "<td>{c}</td>");
        }
        s.push_str("</tr>");
    }
    s.push_str("</tbody></table>");
    s
}

/// Key/value list; values are already HTML.
pub fn facts(items: &[(&str, String)]) -> String {
    let mut s = String::from("<dl class=\"facts\">");
    for (k, v) in items {
        let _ = write!(s, "<dt>{}</dt><dd>{v}</dd>", esc(k));
    }
    s.push_str("</dl>");
    s
}

/// A list page's position and its previous/next links: "51–100 of 230 · previous · next".
/// `query` is appended to each link (e.g. `&job_id=…`, the page's filter). A page past the
/// end shows "0 of N" and a link back.
pub fn pager(offset: u32, limit: u32, shown: usize, total: i64, query: &str) -> String {
    let mut pager = format!(
        "<p class=\"pager\">{} of {total}",
        if shown == 0 {
            "0".to_owned()
        } else {
            format!("{}–{}", offset + 1, offset as usize + shown)
        }
    );
    if offset > 0 {
        let _ = write!(
            pager,
            " · <a href=\"?offset={}{query}\">previous</a>",
            offset.saturating_sub(limit)
        );
    }
    if i64::from(offset) + i64::from(limit) < total {
        let _ = write!(
            pager,
            " · <a href=\"?offset={}{query}\">next</a>",
            offset + limit
        );
    }
    pager.push_str("</p>");
    pager
}

pub fn link(href: &str, text: &str) -> String {
    format!("<a href=\"{}\">{}</a>", esc(href), esc(text))
}

/// A figure from an SVG endpoint; `view` adds azimuth/elevation sliders (3-D figures), `extra`
/// is more controls (HTML with `name`d inputs that become query parameters).
pub fn figure(src: &str, caption: &str, view: bool, extra: &str) -> String {
    let controls = if view {
        "<label>azimuth <input type=\"range\" name=\"azimuth\" min=\"-180\" max=\"180\" \
         value=\"35\"></label><label>elevation <input type=\"range\" name=\"elevation\" \
         min=\"-90\" max=\"90\" value=\"20\"></label>"
    } else {
        ""
    };
    format!(
        "<figure class=\"plot\" data-src=\"{s}\"><img src=\"{s}\" alt=\"{c}\" width=\"800\" \
         height=\"600\"><figcaption>{c}<span class=\"controls\">{controls}{extra}</span>\
         <a href=\"{s}\" download>SVG</a></figcaption><p class=\"field-error plot-error\"></p>\
         </figure>",
        s = esc(src),
        c = esc(caption),
    )
}

/// A live progress bar for a job (the script follows its Server-Sent Events).
pub fn progress(job_id: &str, status: &str, fraction: f64) -> String {
    let pct = (fraction.clamp(0.0, 1.0) * 100.0).round();
    format!(
        "<div class=\"job-status\" data-job=\"{j}\" data-status=\"{st}\">\
         <progress max=\"100\" value=\"{pct}\"></progress> <span class=\"job-text\">{st} \
         {pct}%</span> <span class=\"job-result\"></span></div>",
        j = esc(job_id),
        st = esc(status),
    )
}

/// One form field. `path` is the JSONPath the API reports errors under; `name` the dotted
/// body path the script builds the JSON from; `kind` one of `int`, `float`, `text`, `vec`
/// (comma-separated numbers), `bool`, or `select:<opt1>|<opt2>` (plain values).
pub fn field(label: &str, name: &str, path: &str, kind: &str, value: &str) -> String {
    let input = if let Some(opts) = kind.strip_prefix("select:") {
        let mut s = format!(
            "<select name=\"{}\" data-type=\"text\" data-path=\"{}\">",
            esc(name),
            esc(path)
        );
        for o in opts.split('|').filter(|o| !o.is_empty()) {
            let (v, l) = o.split_once('=').unwrap_or((o, o));
            let sel = if v == value { " selected" } else { "" };
            let _ = write!(s, "<option value=\"{}\"{sel}>{}</option>", esc(v), esc(l));
        }
        s.push_str("</select>");
        s
    } else if kind == "bool" {
        let checked = if value == "true" { " checked" } else { "" };
        format!(
            "<input type=\"checkbox\" name=\"{}\" data-type=\"bool\" data-path=\"{}\"{checked}>",
            esc(name),
            esc(path)
        )
    } else {
        format!(
            "<input name=\"{}\" data-type=\"{}\" data-path=\"{}\" value=\"{}\">",
            esc(name),
            esc(kind),
            esc(path),
            esc(value)
        )
    };
    format!(
        "<div class=\"field\"><label>{}</label>{input}<span class=\"field-error\"></span></div>",
        esc(label)
    )
}

/// A form posting JSON to `endpoint`; `fields` from [`field`].
pub fn form(id: &str, title: &str, endpoint: &str, fields: &[String], submit: &str) -> String {
    format!(
        "<form class=\"api-form\" id=\"{id}\" data-endpoint=\"{e}\"><h2>{t}</h2>{f}\
         <p class=\"form-error field-error\"></p><button type=\"submit\">{s}</button>\
         <div class=\"form-result\"></div></form>",
        id = esc(id),
        e = esc(endpoint),
        t = esc(title),
        f = fields.concat(),
        s = esc(submit),
    )
}

/// Formats a number for display.
pub fn num(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else {
        "–".into()
    }
}

/// One JSON value as page text: numbers to 5 decimals, arrays comma-separated, booleans as
/// yes/no, an absent value (a link label where no pair was near) as "–".
pub fn value_text(v: &serde_json::Value) -> String {
    use serde_json::Value;
    match v {
        Value::Number(n) => n.as_f64().map(|x| num(x, 5)).unwrap_or_default(),
        Value::Array(a) => a.iter().map(value_text).collect::<Vec<_>>().join(", "),
        Value::String(s) => esc(s),
        Value::Bool(b) => if *b { "yes" } else { "no" }.into(),
        Value::Null => "–".into(),
        Value::Object(_) => esc(&v.to_string()),
    }
}

/// Named JSON values as a facts list, each value as [`value_text`] renders it.
pub fn value_facts<'a>(
    items: impl IntoIterator<Item = (&'a str, &'a serde_json::Value)>,
) -> String {
    let rows: Vec<(&str, String)> = items.into_iter().map(|(k, v)| (k, value_text(v))).collect();
    facts(&rows)
}

/// `2026-12-04 06:05:20` (UTC) from an RFC 3339 timestamp: columns stay narrow.
pub fn when(rfc3339: &str) -> String {
    let t = rfc3339.replacen('T', " ", 1);
    t.split('.')
        .next()
        .unwrap_or(&t)
        .trim_end_matches('Z')
        .to_owned()
}

/// The first 8 characters of an id, as lists and links show it.
pub fn short(id: &str) -> &str {
    &id[..8.min(id.len())]
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_pager_counts_from_one_and_links_only_where_there_is_a_page() {
        let p = super::pager;
        assert_eq!(
            p(0, 50, 50, 120, ""),
            "<p class=\"pager\">1–50 of 120 · <a href=\"?offset=50\">next</a></p>"
        );
        assert_eq!(
            p(100, 50, 20, 120, "&job_id=j"),
            "<p class=\"pager\">101–120 of 120 · <a href=\"?offset=50&job_id=j\">previous</a></p>"
        );
        // exactly one full page: no next
        assert_eq!(p(0, 50, 50, 50, ""), "<p class=\"pager\">1–50 of 50</p>");
        // past the end (a stale link): nothing shown, the way back offered
        assert_eq!(
            p(200, 50, 0, 120, ""),
            "<p class=\"pager\">0 of 120 · <a href=\"?offset=150\">previous</a></p>"
        );
        assert_eq!(p(0, 50, 0, 0, ""), "<p class=\"pager\">0 of 0</p>");
    }

    #[test]
    fn markup_characters_are_escaped_to_their_entities() {
        // The five characters HTML reserves in text and quoted attributes, and nothing else.
        assert_eq!(
            super::esc(r#"<a title="x">Tom & Jerry's/é</a>"#),
            "&lt;a title=&quot;x&quot;&gt;Tom &amp; Jerry&#x27;s/é&lt;/a&gt;"
        );
        assert_eq!(super::esc("plain"), "plain");
    }
}
