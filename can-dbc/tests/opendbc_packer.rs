//! Every carmaker checksum against frames packed by opendbc's own
//! `CANPacker` (issue #32): `opendbc/packed.json`, written by
//! `opendbc/check_packer.py` (`check_packer.sh` installs opendbc from PyPI
//! and regenerates or checks it). Each entry is one checksummed message of a
//! platform's DBC, with its own DBC lines and the frames opendbc packed.

use canodom_dbc::{Database, Maker, MakerChecksum};
use serde_json::Value;

const FIXTURE: &str = include_str!("opendbc/packed.json");

#[test]
fn every_maker_checksum_matches_opendbcs_packer_bit_for_bit() {
    let doc: Value = serde_json::from_str(FIXTURE).unwrap();
    let messages = doc["messages"].as_array().unwrap();
    let mut per_platform = std::collections::BTreeMap::<String, (usize, usize)>::new();
    let mut extended = 0;
    for m in messages {
        let name = m["message"].as_str().unwrap();
        let platform = m["platform"].as_str().unwrap();
        let maker = Maker::from_name(m["algorithm"].as_str().unwrap()).unwrap();
        let lines: Vec<&str> = m["dbc_lines"]
            .as_array()
            .unwrap()
            .iter()
            .map(|l| l.as_str().unwrap())
            .collect();
        // opendbc writes some 29-bit ids (Honda Bosch's LKAS_HUD_A, 0x33DA)
        // without the DBC's extended flag and computes their checksum from
        // the number as written (Honda adds 3 for an id above 0x7FF).
        // canodom's database leaves such a message out (an invalid standard
        // id, with a load warning), so the line is given the flag here and
        // the checksum the number opendbc used.
        let address = m["address"].as_u64().unwrap();
        let unflagged_extended = (0x800..0x8000_0000).contains(&address);
        let bo = if unflagged_extended {
            lines[0].replacen(
                &format!("BO_ {address} "),
                &format!("BO_ {} ", address | 0x8000_0000),
                1,
            )
        } else {
            lines[0].to_owned()
        };
        // The sections the crates.io parser expects before the messages.
        let text = format!(
            "VERSION \"\"\n\nNS_ :\n\nBS_:\n\nBU_: XXX\n\n{bo}\n {}\n\n",
            lines[1..].join("\n ")
        );
        let db = Database::parse(&text, "packed.json").unwrap();
        let msg = db
            .messages()
            .first()
            .unwrap_or_else(|| panic!("{platform} {name}: no message in {text:?}"));
        let checksum_name = lines[1].split_whitespace().nth(1).unwrap();
        let handle = db.signal(&format!("{name}.{checksum_name}")).unwrap();
        let id = u32::try_from(address).unwrap();
        if unflagged_extended {
            assert_eq!(msg.id().raw(), id, "{name}");
            extended += 1;
        } else {
            assert_eq!(msg.id().to_dbc(), id, "{name}");
        }
        let c = MakerChecksum::new(maker, id, handle, msg.length()).unwrap();
        // The bytes the checksum signal occupies: a flipped bit elsewhere
        // must be caught.
        let mut mask = vec![0u8; msg.length()];
        msg.signal(checksum_name).unwrap().or_bit_mask(&mut mask);
        // The last byte the checksum signal leaves free: every algorithm
        // covers it (Subaru leaves byte 0 out wherever its checksum lies).
        let free = mask.iter().rposition(|&b| b == 0).unwrap();
        let frames = m["frames"].as_array().unwrap();
        for f in frames {
            let hex = f.as_str().unwrap();
            let data: Vec<u8> = (0..hex.len())
                .step_by(2)
                .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
                .collect();
            assert_eq!(data.len(), msg.length(), "{platform} {name}");
            assert_eq!(
                c.compute(&data),
                handle.raw(&data).unwrap(),
                "{platform} {name} ({maker:?}): {hex}"
            );
            assert!(c.is_valid(&data));
            let mut bad = data.clone();
            bad[free] ^= 0x80;
            assert!(
                !c.is_valid(&bad),
                "{platform} {name}: flipped byte {free} passes"
            );
            let mut again = data.clone();
            again[..].iter_mut().zip(&mask).for_each(|(b, m)| *b &= !m);
            c.apply(&mut again).unwrap();
            assert_eq!(
                again, data,
                "{platform} {name}: apply writes opendbc's frame"
            );
        }
        let e = per_platform.entry(platform.to_owned()).or_default();
        e.0 += 1;
        e.1 += frames.len();
    }
    for (platform, (msgs, frames)) in &per_platform {
        println!("{platform}: {msgs} messages, {frames} frames identical");
    }
    println!("{extended} messages with a 29-bit id written without the extended flag");
    // Every platform of the script compared, Honda Bosch's 29-bit ids among them.
    assert_eq!(per_platform.len(), 12, "{per_platform:?}");
    assert!(extended > 0);
}
