//! `canodom decode` agrees with cantools on every message of every DBC in
//! data/dbc (vectors from fixtures/cantools/gen_decode_vectors.py).

use canodom::cmd::decode::{DecodeArgs, decode};
use canodom_dbc::Database;
use serde_json::Value;

/// Whether cantools cannot load the data/dbc file `name` (the list and the
/// reasons: data/dbc/cantools-cannot-load.txt, shared with can-dbc's tests).
fn cantools_refuses(name: &str) -> bool {
    include_str!("../../data/dbc/cantools-cannot-load.txt")
        .lines()
        .filter(|l| !l.starts_with('#'))
        .filter_map(|l| l.split_whitespace().next())
        .any(|file| file == name)
}

#[test]
fn decode_agrees_with_cantools_on_every_shared_dbc() {
    let fixtures = crate::util::manifest().join("tests/fixtures/cantools");
    let dbc_dir = crate::util::manifest().join("../data/dbc");
    let mut files = 0;
    let mut compared = 0;
    for entry in std::fs::read_dir(&dbc_dir).unwrap() {
        let path = entry.unwrap().path();
        // Files cantools 45.1 refuses to load (gen_decode_vectors.py prints
        // why): nothing to compare with.
        if path.extension().is_none_or(|e| e != "dbc")
            || path
                .file_name()
                .and_then(|n| n.to_str())
                .is_some_and(cantools_refuses)
        {
            continue;
        }
        let name = path.file_stem().unwrap().to_str().unwrap().to_owned();
        let log = fixtures.join(format!("{name}.log"));
        let expected = std::fs::read_to_string(fixtures.join(format!("{name}.expected.jsonl")))
            .unwrap_or_else(|_| panic!("no vectors for {name}: run gen_decode_vectors.py"));
        let db = Database::from_file(&path).unwrap();
        let args = DecodeArgs {
            dbc: path.clone(),
            log: log.clone(),
            all: true,
            strict: true,
            interface: None,
        };
        let mut out = Vec::new();
        let input = std::io::BufReader::new(std::fs::File::open(&log).unwrap());
        let counts = decode(&db, input, &mut out, &args, &mut std::io::sink()).unwrap();
        let ours: Vec<Value> = String::from_utf8(out)
            .unwrap()
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        let theirs: Vec<Value> = expected
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        assert_eq!(ours.len(), theirs.len(), "{name}: {counts:?}");
        for (i, (o, t)) in ours.iter().zip(&theirs).enumerate() {
            assert_eq!(o["id"], t["id"], "{name} line {}", i + 1);
            assert_eq!(o["extended"], t["extended"], "{name} line {}", i + 1);
            if t.get("skip").is_some() {
                continue;
            }
            assert_eq!(o["name"], t["name"], "{name} line {}", i + 1);
            let (os, ts) = (
                o["signals"].as_object().unwrap(),
                t["signals"].as_object().unwrap(),
            );
            let okeys: Vec<_> = os.keys().collect();
            let tkeys: Vec<_> = ts.keys().collect();
            assert_eq!(okeys, tkeys, "{name} line {}: signals present", i + 1);
            for (k, tv) in ts {
                assert_eq!(os[k].as_f64(), tv.as_f64(), "{name} line {}: {k}", i + 1);
            }
            compared += 1;
        }
        files += 1;
    }
    println!("{files} DBC files, {compared} frames identical to cantools");
    assert_eq!(files, 13);
    assert!(compared > 2000);
}
