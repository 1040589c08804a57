//! The car platforms canodom has a ready configuration for (issue #32):
//! for each, opendbc's DBC (carried in data/dbc, MIT, © comma.ai) and the
//! configuration as opendbc's `car/<maker>/carstate.py` reads the wheel
//! speeds and the steering angle (signs, units, factors), the wheelbase and
//! steering ratio from its `values.py`, typical treads and wheel diameters
//! marked "check these"; the names `canodom config init --car` takes for
//! them; and, for the platforms opendbc knows that have none, why. Pure:
//! the texts are compiled in; writing them is the daemon's job.
//!
//! Every configuration is checked by drives packed with opendbc's own
//! packer and replayed (can-dbc/tests/opendbc/drives.sh).

mod opendbc_cars;
pub use opendbc_cars::OPENDBC_CARS;

/// What `config init --list` ends with: what a preset gives on a car that
/// is not the platform's typical one, measured on drives packed by
/// opendbc's packer (README "What a preset gives on your car").
pub const LIST_FOOTER: &str = "\
Every [vehicle] above is the platform's typical car: yours differs. On drives packed by
opendbc's packer (README \"What a preset gives on your car\"; 642-805 m, 0.7 g turns) a
preset ends 0.002-0.23 % of the distance off on its own car and 0.27-3.7 % on a car whose
treads are 2 % wider. One rear tyre 0.3-0.5 % larger than the other (wear, pressure) is
learnt once the car has turned tightly both ways: 0.002-0.43 % (the rear wheels alone:
3.3-58 %). A front tyre or a steering ratio 5 % off costs nothing. Measure the rear tread,
or calibrate it with the rear wheels' ratio (README \"Calibrate it\").";

/// The README section a refusal points to for writing `[signals]` by hand.
pub const README_BY_HAND: &str = "Configure it by hand";

/// A platform `config init` knows.
#[derive(Debug, Clone, Copy)]
pub struct Platform {
    /// The name `--car` takes.
    pub name: &'static str,
    /// Other names `--car` takes for it (see [`platform`]).
    pub aliases: &'static [&'static str],
    /// The cars it covers.
    pub cars: &'static str,
    /// What the configuration reads.
    pub provides: &'static str,
    /// The DBC's file name, written beside the configuration.
    pub dbc_file: &'static str,
    /// The DBC's text (opendbc's, carried in data/dbc).
    pub dbc_text: &'static str,
    /// The configuration (its example in daemon/examples/, which the
    /// daemon's tests replay).
    pub example: &'static str,
}

/// Every platform, in `--list` order.
pub const PLATFORMS: &[Platform] = &[
    Platform {
        name: "chrysler",
        aliases: &["jeep", "cusw", "chrysler_cusw", "jeep_cherokee", "fca"],
        cars: "Jeep Cherokee 2019-23 (Chrysler CUSW)",
        provides: "WHEEL_SPEEDS_FRONT/REAR (4 m/s magnitudes) signed by GEAR.PRNDL, STEERING angle; Chrysler CRC-8 and counters",
        dbc_file: "opendbc_chrysler_cusw.dbc",
        dbc_text: include_str!("../../data/dbc/opendbc_chrysler_cusw.dbc"),
        example: include_str!("../../daemon/examples/chrysler.toml"),
    },
    Platform {
        name: "gm",
        aliases: &[
            "chevrolet",
            "chevy",
            "cadillac",
            "gmc",
            "buick",
            "gm_global_a",
            "gm_global_a_powertrain",
            "general_motors",
        ],
        cars: "GM global-A (Chevrolet Bolt, Volt, Equinox, Silverado, Cadillac, ...)",
        provides: "EBCMWheelSpdFront/Rear (4 km/h magnitudes) signed by RLWheelDir, PSCMSteeringAngle; no checks on these",
        dbc_file: "opendbc_gm_global_a_powertrain.dbc",
        dbc_text: include_str!("../../data/dbc/opendbc_gm_global_a_powertrain.dbc"),
        example: include_str!("../../daemon/examples/gm.toml"),
    },
    Platform {
        name: "honda",
        aliases: &[
            "honda_nidec",
            "honda_civic",
            "civic",
            "honda_civic_touring_2016_can",
            "honda_bosch",
            "honda_civic_hatchback_ex_2017_can",
        ],
        cars: "Honda Civic 2016-21 (Nidec, and Bosch hatchback: the same messages), Accord 2018-22, CR-V 2017-22, Acura TLX 2021-",
        provides: "WHEEL_SPEEDS (4 kph magnitudes) signed by the gear of GEARBOX_CVT or GEARBOX_AUTO (whichever the car sends), STEERING_SENSORS angle; Honda checksums and counter",
        dbc_file: "opendbc_honda_civic_touring_2016_can.dbc",
        dbc_text: include_str!("../../data/dbc/opendbc_honda_civic_touring_2016_can.dbc"),
        example: include_str!("../../daemon/examples/honda.toml"),
    },
    Platform {
        name: "hyundai",
        aliases: &[
            "kia",
            "genesis",
            "hyundai_kia",
            "hyundai_kia_generic",
            "hkg",
            "hyundai_can",
        ],
        cars: "Hyundai / Kia / Genesis on classic CAN (Sonata, Elantra, Santa Fe, Sorento, Niro, ...)",
        provides: "WHL_SPD11 (4 km/h magnitudes), SAS11 angle; no checks (opendbc packs none on these)",
        dbc_file: "opendbc_hyundai_kia_generic.dbc",
        dbc_text: include_str!("../../data/dbc/opendbc_hyundai_kia_generic.dbc"),
        example: include_str!("../../daemon/examples/hyundai.toml"),
    },
    Platform {
        name: "hyundai_canfd",
        aliases: &[
            "kia_canfd",
            "hkg_canfd",
            "genesis_canfd",
            "hyundai_can_fd",
            "canfd",
            "hyundai_ioniq_5",
            "hyundai_ioniq_6",
            "kia_ev6",
            "kia_ev9",
            "genesis_gv60",
        ],
        cars: "Hyundai / Kia / Genesis on CAN FD (Ioniq 5/6, EV6, EV9, GV60, ...)",
        provides: "WHEEL_SPEEDS (4 km/h magnitudes) signed by GEAR_SHIFTER gear, STEERING_SENSORS angle; CAN FD CRC-16 and counters",
        dbc_file: "opendbc_hyundai_canfd.dbc",
        dbc_text: include_str!("../../data/dbc/opendbc_hyundai_canfd.dbc"),
        example: include_str!("../../daemon/examples/hyundai_canfd.toml"),
    },
    Platform {
        name: "mazda",
        aliases: &["mazda_2017", "mazda_cx5", "cx5"],
        cars: "Mazda CX-5 2017-21, CX-9, 3, 6 (2017 bus)",
        provides: "WHEEL_SPEEDS (4 signed kph), STEER angle; no checks (not established)",
        dbc_file: "opendbc_mazda_2017.dbc",
        dbc_text: include_str!("../../data/dbc/opendbc_mazda_2017.dbc"),
        example: include_str!("../../daemon/examples/mazda.toml"),
    },
    Platform {
        name: "nissan",
        aliases: &["nissan_x_trail_2017", "x_trail", "xtrail", "rogue"],
        cars: "Nissan X-Trail 2017, Rogue 2018-20, Altima (not the Leaf: other ids)",
        provides: "WHEEL_SPEEDS_FRONT/REAR (4 kph magnitudes) signed by GEARBOX gear, STEER_ANGLE_SENSOR angle; its counter",
        dbc_file: "opendbc_nissan_x_trail_2017.dbc",
        dbc_text: include_str!("../../data/dbc/opendbc_nissan_x_trail_2017.dbc"),
        example: include_str!("../../daemon/examples/nissan.toml"),
    },
    Platform {
        name: "psa",
        aliases: &[
            "peugeot",
            "citroen",
            "ds",
            "opel",
            "stellantis_psa",
            "psa_aee2010_r3",
            "aee2010",
        ],
        cars: "Peugeot / Citroen / DS / Opel on AEE2010 R3 (Peugeot 208, 2008, ...)",
        provides: "Dyn4_FRE (4 km/h magnitudes), STEERING_ALT angle; no checks opendbc packs",
        dbc_file: "opendbc_psa_aee2010_r3.dbc",
        dbc_text: include_str!("../../data/dbc/opendbc_psa_aee2010_r3.dbc"),
        example: include_str!("../../daemon/examples/psa.toml"),
    },
    Platform {
        name: "subaru",
        aliases: &[
            "subaru_global",
            "subaru_global_2017",
            "impreza",
            "crosstrek",
            "forester",
        ],
        cars: "Subaru global platform (Impreza, Crosstrek, Forester, Outback 2017-19, ...)",
        provides: "Wheel_Speeds (4 kph magnitudes) signed by Transmission gear, Steering_Torque angle; Subaru checksums and counters",
        dbc_file: "opendbc_subaru_global_2017.dbc",
        dbc_text: include_str!("../../data/dbc/opendbc_subaru_global_2017.dbc"),
        example: include_str!("../../daemon/examples/subaru.toml"),
    },
    Platform {
        name: "toyota",
        aliases: &[
            "lexus",
            "toyota_2017",
            "toyota_nodsu_pt",
            "toyota_tnga_k_pt",
            "toyota_new_mc_pt",
            "toyota_secoc",
            "toyota_secoc_pt",
            "tss2",
            "tnga",
        ],
        cars: "Toyota / Lexus with the 2017 powertrain bus (RAV4, Corolla, Camry, Prius, ...)",
        provides: "WHEEL_SPEEDS (4 signed km/h), STEER_ANGLE_SENSOR (angle + fraction); no counters or checksums on these",
        dbc_file: "opendbc_toyota_2017.dbc",
        dbc_text: include_str!("../../data/dbc/opendbc_toyota_2017.dbc"),
        example: include_str!("../../daemon/examples/toyota.toml"),
    },
    Platform {
        name: "vw_mqb",
        aliases: &[
            "vw",
            "volkswagen",
            "volkswagen_mqb",
            "mqb",
            "audi",
            "skoda",
            "seat",
            "golf",
        ],
        cars: "VW MQB (Golf 7, Passat B8, Tiguan, Audi A3, Skoda Octavia, ...)",
        provides: "ESP_19 (4 km/h magnitudes) signed by Gateway_73 gear, LWI_01 angle + sign bit, ESP_02 yaw rate + sign bit; VW CRC and counters",
        dbc_file: "opendbc_vw_mqb.dbc",
        dbc_text: include_str!("../../data/dbc/opendbc_vw_mqb.dbc"),
        example: include_str!("../../daemon/examples/vw_mqb.toml"),
    },
];

/// The platform `name` means: its own name, one of its aliases (maker
/// names, opendbc's DBC names), or an opendbc car name whose powertrain DBC
/// carries its messages ([`OPENDBC_CARS`], from opendbc's `values.py`); in
/// any case, with `-`, spaces or `_` between words and opendbc's
/// `_generated` suffix or an `opendbc_` prefix. Nothing else: a name that is
/// none of these is not taken for its maker's platform (opendbc's Leaf, a
/// CAN FD Accord or a Nidec Acura are on other buses than their maker's
/// preset), [`suggestions`] are offered instead.
pub fn platform(name: &str) -> Option<&'static Platform> {
    let key = lookup_key(name);
    if not_covered(&key).is_some() {
        return None;
    }
    let by_name = |k: &str| {
        PLATFORMS
            .iter()
            .find(|p| p.name == k || p.aliases.contains(&k))
    };
    by_name(&key).or_else(|| {
        OPENDBC_CARS
            .binary_search_by(|(car, _)| (*car).cmp(key.as_str()))
            .ok()
            .and_then(|i| by_name(OPENDBC_CARS[i].1))
    })
}

/// `name` as the name table spells it: normalised, opendbc's file name
/// decorations taken off.
pub fn lookup_key(name: &str) -> String {
    let key = normalise(name);
    let key = key.strip_suffix("_generated").unwrap_or(&key);
    let key = key.strip_prefix("opendbc_").unwrap_or(key);
    key.strip_suffix(".dbc").unwrap_or(key).to_owned()
}

/// The names `--car` takes that are nearest `name` (at most five, best
/// first): those it starts, else those alike in spelling (Jaro-Winkler ≥
/// 0.85), for a refusal to offer.
pub fn suggestions(name: &str) -> Vec<&'static str> {
    let key = lookup_key(name);
    let names = PLATFORMS
        .iter()
        .flat_map(|p| std::iter::once(p.name).chain(p.aliases.iter().copied()))
        .chain(OPENDBC_CARS.iter().map(|(car, _)| *car));
    let mut scored: Vec<(f64, &'static str)> = names
        .filter_map(|n| {
            let score = if n.starts_with(&format!("{key}_")) || key.starts_with(&format!("{n}_")) {
                1.0
            } else {
                strsim::jaro_winkler(&key, n)
            };
            (score >= 0.85).then_some((score, n))
        })
        .collect();
    scored.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(b.1)));
    scored.dedup_by(|a, b| a.1 == b.1);
    scored.into_iter().take(5).map(|(_, n)| n).collect()
}

/// opendbc platforms `config init` has no configuration for, and why (what
/// `--car` says instead of taking the maker's other platform).
const NOT_COVERED: &[(&str, &str)] = &[
    (
        "vw_pq",
        "opendbc's carstate reads no per-wheel speeds on VW PQ (it reads Bremse_1's vehicle speed)",
    ),
    (
        "volkswagen_pq",
        "opendbc's carstate reads no per-wheel speeds on VW PQ (it reads Bremse_1's vehicle speed)",
    ),
    (
        "vw_meb",
        "VW MEB's bus is not the MQB one; no configuration yet",
    ),
    (
        "vw_mlb",
        "VW MLB's bus is not the MQB one; no configuration yet",
    ),
    (
        "tesla",
        "opendbc's carstate reads no per-wheel speeds on Tesla (it reads DI_speed's vehicle speed)",
    ),
    (
        "ford",
        "opendbc's carstate reads no per-wheel speeds on Ford (it reads BrakeSysFeatures' vehicle speed)",
    ),
    (
        "lincoln",
        "opendbc's carstate reads no per-wheel speeds on Ford (it reads BrakeSysFeatures' vehicle speed)",
    ),
    (
        "rivian",
        "opendbc's carstate reads no per-wheel speeds on Rivian (it reads ESP_Status's vehicle speed)",
    ),
    (
        "chrysler_pacifica",
        "opendbc's carstate reads no per-wheel speeds on the Pacifica (SPEED_1's two speeds)",
    ),
    (
        "ram",
        "opendbc's carstate reads no per-wheel speeds on Ram (ESP_8's vehicle speed)",
    ),
    (
        "chrysler_ram",
        "opendbc's carstate reads no per-wheel speeds on Ram (ESP_8's vehicle speed)",
    ),
    (
        "subaru_outback_2015",
        "a pre-global Subaru: another bus than the global platform's",
    ),
    (
        "subaru_outback_2019",
        "a pre-global Subaru: another bus than the global platform's",
    ),
    (
        "subaru_forester_2017",
        "a pre-global Subaru: another bus than the global platform's",
    ),
    (
        "subaru_global_2020_hybrid",
        "the hybrid's wheel speeds are on another bus; no configuration yet",
    ),
    (
        "nissan_leaf",
        "the Leaf's front wheel speeds and gear are other messages (0x284, 0x421) than the X-Trail's; no configuration yet",
    ),
    (
        "honda_accord_11g",
        "the Accord 2023- is on Honda's CAN FD bus (opendbc's honda_common_canfd); no configuration yet",
    ),
];

/// Why `key` (normalised) has no configuration, if it names a platform
/// opendbc knows that `config init` does not cover.
pub fn not_covered(key: &str) -> Option<&'static str> {
    NOT_COVERED
        .iter()
        .find(|(k, _)| key == *k || key.starts_with(&format!("{k}_")))
        .map(|(_, why)| *why)
}

/// Lower case, words joined by `_`.
pub fn normalise(name: &str) -> String {
    name.trim()
        .to_lowercase()
        .split(['-', ' ', '_', '/'])
        .filter(|w| !w.is_empty())
        .collect::<Vec<_>>()
        .join("_")
}

impl Platform {
    /// The configuration text: the example with the DBC beside it and the
    /// given interface, headed by what to check.
    pub fn config_text(&self, interface: &str) -> String {
        use std::fmt::Write as _;
        let mut out = format!(
            "# Written by `canodom config init --car {}`: {}.\n\
             # CHECK THESE before trusting the pose: the [vehicle] values are the\n\
             # platform's typical ones (wheelbase and steering ratio from opendbc's\n\
             # values.py; treads and wheel diameter typical) -- measure your car or\n\
             # calibrate (`canodom calibrate`, README \"Calibrate it\").\n\n",
            self.name, self.cars
        );
        for line in self.example.lines() {
            if line.starts_with("dbc = ") {
                let _ = writeln!(out, "dbc = \"{}\"", self.dbc_file);
            } else if line.starts_with("interface = ") {
                let _ = writeln!(out, "interface = {interface:?}");
            } else if line == "[vehicle]" {
                out.push_str("[vehicle]                        # check these\n");
            } else {
                out.push_str(line);
                out.push('\n');
            }
        }
        out
    }

    /// The DBC's text.
    pub fn dbc_text(&self) -> &'static str {
        self.dbc_text
    }
}

/// Why `--car car` has no configuration, and what to do instead: the
/// reason for a platform opendbc knows that `config init` does not cover,
/// else the close names (issue #45: an unknown name was mapped to its
/// maker's platform silently).
pub fn refusal(car: &str) -> String {
    let names: Vec<&str> = PLATFORMS.iter().map(|p| p.name).collect();
    let by_hand = format!("or write [signals] by hand (README \"{README_BY_HAND}\")");
    if let Some(why) = not_covered(&lookup_key(car)) {
        return format!(
            "no configuration for `{car}`: {why}. Platforms: {} (canodom config init --list); {by_hand}",
            names.join(", ")
        );
    }
    let close = suggestions(car);
    let close = if close.is_empty() {
        String::new()
    } else {
        format!("did you mean {}? ", close.join(", "))
    };
    format!(
        "unknown platform `{car}`: {close}`--car` takes {}, their aliases and the opendbc car names \
         on their buses (canodom config init --list); a name that is none of these is not taken for \
         its maker's platform, whose bus it may not share; {by_hand}",
        names.join(", ")
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn makers_and_opendbcs_names_find_their_platform() {
        for (name, platform_name) in [
            ("Subaru", "subaru"),
            ("subaru_global_2017_generated", "subaru"),
            ("SUBARU_IMPREZA", "subaru"),
            ("Kia", "hyundai"),
            ("HYUNDAI_SONATA", "hyundai"),
            ("hyundai_kia_generic", "hyundai"),
            ("hyundai_canfd_generated", "hyundai_canfd"),
            ("hyundai-canfd", "hyundai_canfd"),
            ("KIA_EV6", "hyundai_canfd"),
            ("Jeep", "chrysler"),
            ("JEEP_CHEROKEE_5TH_GEN", "chrysler"),
            ("chrysler_cusw", "chrysler"),
            ("CHEVROLET_BOLT_EUV", "gm"),
            ("gm_global_a_powertrain_generated", "gm"),
            ("Nissan", "nissan"),
            ("NISSAN_ROGUE", "nissan"),
            ("mazda_2017", "mazda"),
            ("Peugeot", "psa"),
            ("psa_aee2010_r3", "psa"),
            ("Lexus", "toyota"),
            ("toyota_nodsu_pt_generated", "toyota"),
            ("Volkswagen", "vw_mqb"),
            ("VW MQB", "vw_mqb"),
            ("opendbc_vw_mqb.dbc", "vw_mqb"),
            ("honda_civic_hatchback_ex_2017_can_generated", "honda"),
            ("Honda Bosch", "honda"),
            // opendbc's Accord 2018-22 is on the Bosch Civic's DBC, its
            // SecOC Toyotas on the 2017 bus's (issue #45: both named).
            ("HONDA_ACCORD", "honda"),
            ("honda_accord", "honda"),
            ("ACURA_TLX_2G", "honda"),
            ("toyota_secoc", "toyota"),
            ("TOYOTA_RAV4_PRIME", "toyota"),
            ("toyota_secoc_pt_generated", "toyota"),
        ] {
            assert_eq!(
                platform(name).map(|p| p.name),
                Some(platform_name),
                "{name}"
            );
        }
        // The maker's other buses are not taken for this one.
        for name in [
            "vw_pq",
            "VOLKSWAGEN_PQ",
            "tesla",
            "FORD_F_150_MK14",
            "subaru_outback_2015_generated",
            "CHRYSLER_PACIFICA_2018",
            "RAM_1500_5TH_GEN",
            // A maker's name is no platform where its cars are on several
            // buses (issue #45: these mapped silently to the maker's preset).
            "acura",
            "ACURA_ILX",
            "HONDA_PILOT",
            "HONDA_ACCORD_11G",
            "NISSAN_LEAF",
            "leaf",
            "HONDA_CIVIC_2022",
            "HYUNDAI_SOMETHING_NEW",
        ] {
            assert!(platform(name).is_none(), "{name}");
        }
        assert!(platform("trabant").is_none());
    }

    #[test]
    fn an_unknown_name_is_offered_the_close_ones() {
        assert_eq!(suggestions("acura")[0], "acura_tlx_2g");
        assert!(
            suggestions("hona").contains(&"honda"),
            "{:?}",
            suggestions("hona")
        );
        assert!(
            suggestions("toyota_rav4_tss3").contains(&"toyota_rav4_tss2"),
            "{:?}",
            suggestions("toyota_rav4_tss3")
        );
        assert!(suggestions("trabant").is_empty());
    }

    #[test]
    fn opendbcs_car_names_are_sorted_and_name_platforms() {
        assert!(OPENDBC_CARS.windows(2).all(|w| w[0].0 < w[1].0));
        for (car, p) in OPENDBC_CARS {
            assert!(PLATFORMS.iter().any(|q| q.name == *p), "{car}: {p}");
            assert_eq!(platform(car).map(|q| q.name), Some(*p), "{car}");
        }
    }

    #[test]
    fn the_readme_sections_pointed_to_exist() {
        let readme = include_str!("../../README.md");
        for section in [
            README_BY_HAND,
            "What a preset gives on your car",
            "Calibrate it",
        ] {
            assert!(
                readme
                    .lines()
                    .any(|l| l.starts_with('#') && l.trim_start_matches('#').trim() == section),
                "README.md has no section \"{section}\""
            );
            assert!(
                section == README_BY_HAND || LIST_FOOTER.contains(&format!("\"{section}\"")),
                "{section}"
            );
        }
    }

    #[test]
    fn every_platform_is_headed_by_what_to_check() {
        for p in PLATFORMS {
            let text = p.config_text("vcan0");
            assert!(
                text.contains("CHECK THESE") && text.contains("# check these"),
                "{}",
                p.name
            );
            assert!(
                text.contains(&format!("dbc = \"{}\"", p.dbc_file)),
                "{}",
                p.name
            );
            assert!(text.contains("interface = \"vcan0\""), "{}", p.name);
            // The yaw-rate sensor on wherever the DBC carries one (issue
            // #45): the aided estimator carries the pose only once it shows
            // the wheels off, so the gyro costs nothing where they are exact.
            let gyro = text.lines().any(|l| l.starts_with("yaw_rate = "));
            let carries_one =
                ["vw_mqb", "toyota", "hyundai", "hyundai_canfd", "gm"].contains(&p.name);
            assert_eq!(gyro, carries_one, "{}", p.name);
            assert!(
                !text.contains("# yaw_rate ="),
                "{}: a commented-out line",
                p.name
            );
        }
    }

    #[test]
    fn an_unknown_car_is_refused_with_the_close_names() {
        // These mapped silently to their maker's preset (issue #45).
        for (car, close) in [("acura", "acura_tlx_2g"), ("HONDA_PILOT", "honda")] {
            assert!(platform(car).is_none(), "{car}");
            let r = refusal(car);
            assert!(
                r.contains("unknown platform") && r.contains(&format!("did you mean {close}")),
                "{r}"
            );
        }
        let r = refusal("tesla");
        assert!(
            r.contains("per-wheel speeds") && r.contains(README_BY_HAND),
            "{r}"
        );
        let r = refusal("NISSAN_LEAF");
        assert!(r.contains("0x284"), "{r}");
    }
}
