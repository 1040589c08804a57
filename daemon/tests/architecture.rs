//! The architecture the README draws, checked on the source tree: which
//! crate may depend on which, no module cycle inside any crate, and the
//! daemon kept to scheduling and the command line (its `src/` small).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The workspace root (this crate is `daemon/`).
fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .to_path_buf()
}

/// Every workspace member folder, from the root manifest.
fn members() -> Vec<String> {
    let text = std::fs::read_to_string(root().join("Cargo.toml")).unwrap();
    let manifest: toml::Table = text.parse().unwrap();
    manifest["workspace"]["members"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m.as_str().unwrap().to_owned())
        .collect()
}

/// A member's package name and the workspace crates it depends on
/// (normal dependencies only: dev-dependencies may test across rooms).
fn package(member: &str) -> (String, BTreeSet<String>) {
    let text = std::fs::read_to_string(root().join(member).join("Cargo.toml")).unwrap();
    let manifest: toml::Table = text.parse().unwrap();
    let name = manifest["package"]["name"].as_str().unwrap().to_owned();
    let deps = manifest
        .get("dependencies")
        .and_then(toml::Value::as_table)
        .map(|t| {
            t.keys()
                .filter(|k| k.starts_with("canodom"))
                .cloned()
                .collect()
        })
        .unwrap_or_default();
    (name, deps)
}

#[test]
fn no_crate_but_the_binary_depends_on_the_daemon_crate() {
    for member in members() {
        let (name, deps) = package(&member);
        assert!(
            !deps.contains("canodom"),
            "{name} ({member}/Cargo.toml) depends on the daemon crate `canodom`; \
             move what it needs into a library crate"
        );
    }
}

#[test]
fn the_pure_crates_stay_pure() {
    // fusion and calib are maths and state: no I/O crates, no async runtime.
    for member in ["fusion", "calib"] {
        let text = std::fs::read_to_string(root().join(member).join("Cargo.toml")).unwrap();
        let manifest: toml::Table = text.parse().unwrap();
        let deps = manifest["dependencies"].as_table().unwrap();
        for forbidden in ["tokio", "socketcan", "canodom-can", "canodom-params"] {
            assert!(
                !deps.contains_key(forbidden),
                "{member} depends on {forbidden}"
            );
        }
    }
}

#[test]
fn the_recordings_crate_leaves_the_runtime_to_the_daemon() {
    // export runs on threads of its own, never inside the daemon's runtime;
    // the Foxglove SDK's WebSocket server brings a runtime of its own.
    let text = std::fs::read_to_string(root().join("export/Cargo.toml")).unwrap();
    let manifest: toml::Table = text.parse().unwrap();
    let deps = manifest["dependencies"].as_table().unwrap();
    for forbidden in ["tokio", "tokio-util", "socketcan"] {
        assert!(
            !deps.contains_key(forbidden),
            "export depends on {forbidden}"
        );
    }
}

#[test]
fn the_live_calibration_is_a_state_machine() {
    // The wire side of the calibrator takes bus timestamps and returns
    // frames and effects to carry out: no runtime, no socket, no clock.
    let text = std::fs::read_to_string(root().join("live/Cargo.toml")).unwrap();
    let manifest: toml::Table = text.parse().unwrap();
    let deps = manifest["dependencies"].as_table().unwrap();
    for forbidden in ["tokio", "tokio-util", "socketcan", "canodom-ros2"] {
        assert!(!deps.contains_key(forbidden), "live depends on {forbidden}");
    }
    let code = std::fs::read_to_string(root().join("live/src/lib.rs")).unwrap();
    for clock in ["SystemTime::now", "Instant::now"] {
        assert!(!code.contains(clock), "live reads the clock ({clock})");
    }
}

#[test]
fn the_dds_stack_stays_in_the_ros2_crate() {
    // ROS 2 (#43): only the binary uses `canodom-ros2`, and only it names
    // the DDS stack, so the libraries and the Python package build without
    // it; like export, it runs on a thread of its own, not on tokio.
    for member in members() {
        let text = std::fs::read_to_string(root().join(&member).join("Cargo.toml")).unwrap();
        let manifest: toml::Table = text.parse().unwrap();
        let Some(deps) = manifest.get("dependencies").and_then(toml::Value::as_table) else {
            continue;
        };
        if member != "daemon" {
            assert!(
                !deps.contains_key("canodom-ros2"),
                "{member} depends on canodom-ros2: only the daemon may"
            );
        }
        if member != "ros2" {
            for dds in ["rustdds", "ros2-client", "dust_dds"] {
                assert!(!deps.contains_key(dds), "{member} depends on {dds}");
            }
        }
    }
    let text = std::fs::read_to_string(root().join("ros2/Cargo.toml")).unwrap();
    let manifest: toml::Table = text.parse().unwrap();
    let deps = manifest["dependencies"].as_table().unwrap();
    for forbidden in ["tokio", "tokio-util", "socketcan"] {
        assert!(!deps.contains_key(forbidden), "ros2 depends on {forbidden}");
    }
}

#[test]
fn the_gnss_crate_stands_alone_with_its_io_in_the_client() {
    // Live GNSS (#46): `gnss` uses no workspace crate (so never the daemon)
    // and no runtime, and its decoding, acceptance, backoff and status are
    // pure: only `client` (gpsd) and `serial` (a receiver on a serial port)
    // touch sockets, devices and threads.
    let text = std::fs::read_to_string(root().join("gnss/Cargo.toml")).unwrap();
    let manifest: toml::Table = text.parse().unwrap();
    let deps = manifest["dependencies"].as_table().unwrap();
    for dep in deps.keys() {
        assert!(!dep.starts_with("canodom"), "gnss depends on {dep}");
        assert!(
            !["tokio", "tokio-util", "socketcan"].contains(&dep.as_str()),
            "gnss depends on {dep}"
        );
    }
    for (module, text) in modules("gnss") {
        if module == "client" || module == "serial" {
            continue;
        }
        for io in [
            "std::net",
            "std::thread",
            "std::fs",
            "TcpStream",
            "Instant::now",
            "SystemTime",
        ] {
            assert!(
                !text.contains(io),
                "gnss::{module} uses {io}: only gnss::client and gnss::serial do I/O"
            );
        }
    }
}

/// The modules of one crate's `src/`, by path (`cmd::calibrate`), with their
/// non-test, non-comment text.
fn modules(member: &str) -> BTreeMap<String, String> {
    let src = root().join(member).join("src");
    let mut out = BTreeMap::new();
    let mut stack = vec![src.clone()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
                continue;
            }
            if path.extension().is_none_or(|e| e != "rs") {
                continue;
            }
            let rel = path.strip_prefix(&src).unwrap().with_extension("");
            let mut parts: Vec<String> = rel
                .iter()
                .map(|p| p.to_string_lossy().into_owned())
                .collect();
            match parts.last().map(String::as_str) {
                Some("lib" | "main") => continue,
                Some("mod") => {
                    parts.pop();
                }
                _ => {}
            }
            let text = std::fs::read_to_string(&path).unwrap();
            // Unit tests may reach anywhere; only the code's own edges count.
            let code = text.split("#[cfg(test)]").next().unwrap_or_default();
            let code: String = code
                .lines()
                .filter(|l| !l.trim_start().starts_with("//"))
                .collect::<Vec<_>>()
                .join("\n");
            out.insert(parts.join("::"), code);
        }
    }
    out
}

/// The module paths `code` (of module `this`) names through `crate::` or `super::`.
fn edges(this: &str, code: &str, modules: &BTreeMap<String, String>) -> BTreeSet<String> {
    let parent = this.rsplit_once("::").map(|(p, _)| p);
    let mut out = BTreeSet::new();
    for (prefix, base) in [("crate::", None), ("super::", parent)] {
        for (at, _) in code.match_indices(prefix) {
            let before = code[..at].chars().last();
            if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
                continue;
            }
            let rest = &code[at + prefix.len()..];
            let path: String = rest
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_' || *c == ':')
                .collect();
            let segments: Vec<&str> = path.split("::").filter(|s| !s.is_empty()).collect();
            // The longest prefix of the path that is a module.
            for n in (1..=segments.len()).rev() {
                let name = segments[..n].join("::");
                let full = match base {
                    Some(b) => format!("{b}::{name}"),
                    None => name,
                };
                if full != this && modules.contains_key(&full) {
                    out.insert(full);
                    break;
                }
            }
        }
    }
    out
}

/// A module cycle of `modules` (the path, first module repeated last), if any.
fn find_cycle(modules: &BTreeMap<String, String>) -> Option<Vec<String>> {
    fn visit<'a>(
        node: &'a str,
        graph: &'a BTreeMap<&'a str, BTreeSet<String>>,
        colour: &mut BTreeMap<&'a str, u8>,
        stack: &mut Vec<&'a str>,
    ) -> Option<Vec<String>> {
        // Grey (1) while on the stack, black (2) when done.
        colour.insert(node, 1);
        stack.push(node);
        for next in &graph[node] {
            match colour.get(next.as_str()) {
                Some(1) => {
                    let start = stack.iter().position(|s| s == next).unwrap_or(0);
                    let mut cycle: Vec<String> =
                        stack[start..].iter().map(|s| (*s).to_owned()).collect();
                    cycle.push(next.clone());
                    return Some(cycle);
                }
                Some(_) => {}
                None => {
                    let key = graph.get_key_value(next.as_str()).unwrap().0;
                    if let Some(c) = visit(key, graph, colour, stack) {
                        return Some(c);
                    }
                }
            }
        }
        stack.pop();
        colour.insert(node, 2);
        None
    }
    let graph: BTreeMap<&str, BTreeSet<String>> = modules
        .iter()
        .map(|(m, code)| (m.as_str(), edges(m, code, modules)))
        .collect();
    let mut colour = BTreeMap::new();
    for node in graph.keys() {
        if !colour.contains_key(node)
            && let Some(cycle) = visit(node, &graph, &mut colour, &mut Vec::new())
        {
            return Some(cycle);
        }
    }
    None
}

#[test]
fn no_crate_has_a_module_cycle() {
    for member in members() {
        if let Some(cycle) = find_cycle(&modules(&member)) {
            panic!("{member}: module cycle {}", cycle.join(" -> "));
        }
    }
}

#[test]
fn the_cycle_finder_sees_a_cycle() {
    // The check above must be able to fail: two modules naming each other.
    let mut modules = BTreeMap::new();
    modules.insert("a".to_owned(), "use crate::b::X;".to_owned());
    modules.insert("b".to_owned(), "fn f() { crate::a::g() }".to_owned());
    modules.insert("c::d".to_owned(), "use super::e;".to_owned());
    modules.insert("c::e".to_owned(), String::new());
    assert_eq!(
        edges("a", &modules["a"], &modules),
        BTreeSet::from(["b".to_owned()])
    );
    assert_eq!(
        edges("b", &modules["b"], &modules),
        BTreeSet::from(["a".to_owned()])
    );
    assert_eq!(
        edges("c::d", &modules["c::d"], &modules),
        BTreeSet::from(["c::e".to_owned()])
    );
    assert_eq!(
        find_cycle(&modules),
        Some(vec!["a".to_owned(), "b".to_owned(), "a".to_owned()])
    );
    modules.insert("b".to_owned(), "use crate::c::e;".to_owned());
    assert_eq!(find_cycle(&modules), None);
}

#[test]
fn the_daemon_is_only_the_service_and_the_command_line() {
    // The daemon schedules and connects; what it did itself before the split
    // (frames, protocol, files, maths, reports) lives in the library crates.
    const MAX_LINES: usize = 8_000;
    let mut lines = 0;
    let mut stack = vec![root().join("daemon/src")];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else if path.extension().is_some_and(|e| e == "rs") {
                lines += std::fs::read_to_string(&path).unwrap().lines().count();
            }
        }
    }
    assert!(
        lines < MAX_LINES,
        "daemon/src has {lines} lines of Rust (the limit is {MAX_LINES})"
    );
}
