//! The layers of the crate, lowest first; a module may use its own layer and those below,
//! never one above, and no two top-level modules may use each other in a circle. Read from
//! the source (every `crate::<module>` path outside comments; `reachgrasp::<module>` in the
//! CLI), so an import against the order fails here before it is merged.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// `(layer, top-level modules)`, lowest first. `cli` is `src/main.rs`.
const LAYERS: &[(&str, &[&str])] = &[
    (
        "numeric core",
        &[
            "kinematics",
            "geometry",
            "human",
            "mapping",
            "motion",
            "grasp",
            "optim",
            "figures",
            "parallel",
            "wire",
        ],
    ),
    ("store", &["store", "shutdown"]),
    ("jobs/bridge", &["jobs", "bridge"]),
    ("service", &["service", "config"]),
    // The edges that reach the use cases without HTTP: never through the API's handlers or
    // router.
    ("pages and seeding", &["dashboard", "seed"]),
    ("http", &["api"]),
    ("process", &["app", "cli"]),
];

/// What the CLI may take from `api`: the OpenAPI document it prints and the rendering of a
/// plan (`reachgrasp plan` prints what `POST /v1/plans` answers). Its use cases come from
/// `service`.
const CLI_API_ALLOWED: &[&str] = &["api::openapi()", "api::plans::plan_dto("];

fn layer_of(module: &str) -> Option<usize> {
    LAYERS.iter().position(|(_, ms)| ms.contains(&module))
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("readable src") {
        let path = entry.expect("dir entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The top-level module a source file belongs to (`None` for `lib.rs`).
fn module_of(src: &Path, file: &Path) -> Option<String> {
    let rel = file.strip_prefix(src).expect("under src");
    let first = rel.components().next()?.as_os_str().to_str()?.to_owned();
    match first.as_str() {
        "lib.rs" => None,
        "main.rs" => Some("cli".into()),
        f => Some(f.trim_end_matches(".rs").to_owned()),
    }
}

/// Every top-level module named after `prefix` (`crate::` or `reachgrasp::`) in code, with
/// grouped imports (`crate::{a, b::c}`) expanded.
fn used_modules(text: &str, prefix: &str) -> BTreeSet<String> {
    let mut used = BTreeSet::new();
    for line in text.lines() {
        let code = line.split("//").next().unwrap_or("");
        let mut rest = code;
        while let Some(i) = rest.find(prefix) {
            let after = &rest[i + prefix.len()..];
            if let Some(group) = after.strip_prefix('{') {
                let inner = group.split('}').next().unwrap_or("");
                for part in inner.split(',') {
                    let name: String = part
                        .trim()
                        .chars()
                        .take_while(|c| c.is_alphanumeric() || *c == '_')
                        .collect();
                    if !name.is_empty() {
                        used.insert(name);
                    }
                }
            } else {
                let name: String = after
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                if !name.is_empty() {
                    used.insert(name);
                }
            }
            rest = after;
        }
    }
    used
}

/// `module -> (used module -> files that use it)`.
fn imports() -> BTreeMap<String, BTreeMap<String, BTreeSet<String>>> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut graph: BTreeMap<String, BTreeMap<String, BTreeSet<String>>> = BTreeMap::new();
    for file in files {
        let Some(module) = module_of(&src, &file) else {
            continue;
        };
        let text = std::fs::read_to_string(&file).expect("readable source");
        let prefix = if module == "cli" {
            "reachgrasp::"
        } else {
            "crate::"
        };
        for used in used_modules(&text, prefix) {
            if used != module {
                graph
                    .entry(module.clone())
                    .or_default()
                    .entry(used)
                    .or_default()
                    .insert(file.display().to_string());
            }
        }
    }
    graph
}

#[test]
fn every_top_level_module_has_a_layer() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let unplaced: BTreeSet<String> = files
        .iter()
        .filter_map(|f| module_of(&src, f))
        .filter(|m| layer_of(m).is_none())
        .collect();
    assert!(
        unplaced.is_empty(),
        "place these modules in LAYERS: {unplaced:?}"
    );
}

#[test]
fn no_module_imports_from_a_layer_above_its_own() {
    let mut wrong = Vec::new();
    for (module, uses) in imports() {
        let Some(own) = layer_of(&module) else {
            continue;
        };
        for (used, files) in uses {
            if let Some(theirs) = layer_of(&used)
                && theirs > own
            {
                wrong.push(format!(
                    "{module} ({}) uses {used} ({}) in {files:?}",
                    LAYERS[own].0, LAYERS[theirs].0
                ));
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "imports against the layers:\n{}",
        wrong.join("\n")
    );
}

#[test]
fn no_import_circle_between_top_level_modules() {
    let graph = imports();
    let edges: BTreeMap<&str, Vec<&str>> = graph
        .iter()
        .map(|(m, uses)| {
            (
                m.as_str(),
                uses.keys()
                    .map(String::as_str)
                    .filter(|u| layer_of(u).is_some())
                    .collect(),
            )
        })
        .collect();
    // Depth-first search; a grey node met again closes a circle.
    #[derive(Clone, Copy, PartialEq)]
    enum Mark {
        Grey,
        Black,
    }
    fn visit<'a>(
        m: &'a str,
        edges: &BTreeMap<&'a str, Vec<&'a str>>,
        marks: &mut BTreeMap<&'a str, Mark>,
        path: &mut Vec<&'a str>,
    ) -> Option<Vec<&'a str>> {
        match marks.get(m) {
            Some(Mark::Black) => return None,
            Some(Mark::Grey) => {
                let from = path.iter().position(|p| *p == m).unwrap_or(0);
                let mut circle = path[from..].to_vec();
                circle.push(m);
                return Some(circle);
            }
            None => {}
        }
        marks.insert(m, Mark::Grey);
        path.push(m);
        for next in edges.get(m).into_iter().flatten() {
            if let Some(c) = visit(next, edges, marks, path) {
                return Some(c);
            }
        }
        path.pop();
        marks.insert(m, Mark::Black);
        None
    }
    let mut marks = BTreeMap::new();
    for m in edges.keys() {
        let mut path = Vec::new();
        if let Some(circle) = visit(m, &edges, &mut marks, &mut path) {
            panic!("import circle: {}", circle.join(" -> "));
        }
    }
}

#[test]
fn the_cli_calls_use_cases_not_api_handlers() {
    let main = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/main.rs");
    let text = std::fs::read_to_string(main).expect("readable main.rs");
    let mut wrong = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let code = line.split("//").next().unwrap_or("");
        let mut rest = code;
        while let Some(i) = rest.find("reachgrasp::api") {
            let after = &rest[i + "reachgrasp::".len()..];
            if !CLI_API_ALLOWED.iter().any(|a| after.starts_with(a)) {
                wrong.push(format!("src/main.rs:{}: {}", n + 1, line.trim()));
            }
            rest = after;
        }
    }
    assert!(
        wrong.is_empty(),
        "the CLI uses the API beyond {CLI_API_ALLOWED:?}:\n{}",
        wrong.join("\n")
    );
}

#[test]
fn the_reader_sees_grouped_and_inline_paths_and_skips_comments() {
    let text = "use crate::{store, bridge::Hub};\nlet x = crate::api::router();\n// crate::dashboard\n/// [`crate::seed`]";
    let used = used_modules(text, "crate::");
    assert_eq!(
        used,
        ["api", "bridge", "store"]
            .into_iter()
            .map(String::from)
            .collect()
    );
}

/// `api` files that may still name `crate::store`, each with the reason. Handlers reach
/// stored data through `service` only; keep this list empty unless a reason is stronger.
const API_STORE_ALLOWED: &[(&str, &str)] = &[];

#[test]
fn no_api_file_reads_the_store() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src.join("api"), &mut files);
    let mut wrong = Vec::new();
    for file in files {
        let rel = file
            .strip_prefix(&src)
            .expect("under src")
            .display()
            .to_string();
        if API_STORE_ALLOWED.iter().any(|(f, _)| *f == rel) {
            continue;
        }
        let text = std::fs::read_to_string(&file).expect("readable source");
        if used_modules(&text, "crate::").contains("store") {
            wrong.push(rel);
        }
    }
    assert!(
        wrong.is_empty(),
        "these api files use crate::store; call a use case of crate::service instead: {wrong:?}"
    );
}
