//! Tests of the calibration wire codec, its code tables and the
//! `CALIB_PARAMS` assembler (`super`), against the shipped DBC.

use super::*;
use canodom_calib::run::Rejection;
use canodom_calib::session::{Instruction, Phase, Refusal};
use canodom_calib::track::Direction;
use std::collections::HashSet;

#[test]
fn auth_lockout_is_always_0_on_page_0_and_absent_elsewhere() {
    let w = wire();
    let p0 = StatusPage::Progress(Progress {
        state: State::Idle,
        instruction: InstructionCode::None,
        run_index: 0,
        runs_total: 0,
        direction: WireDirection::None,
        start_point: StartPoint::None,
        run_distance_m: 0.0,
        writeback: Writeback::Idle,
        standstill: true,
        writeback_attempts: 0,
        drift: false,
        drift_candidate: false,
    });
    assert_eq!(w.auth_lockout(&w.encode_status(&p0, 3)), Some(false));
    let p5 = w.encode_status(
        &StatusPage::ResultExtra {
            steer_offset_std_rad: 0.0,
            version: 1,
        },
        0,
    );
    assert_eq!(w.auth_lockout(&p5), None);
}

fn wire() -> CalibWire {
    CalibWire::new(BaseId::DEFAULT).unwrap()
}

/// The DBC's `VAL_` table of `message.signal` as (code, name) pairs.
fn table(w: &CalibWire, message: &str, signal: &str) -> Vec<(i64, String)> {
    w.database()
        .message_by_name(message)
        .unwrap()
        .signal(signal)
        .unwrap()
        .value_descriptions()
        .to_vec()
}

fn same_table(w: &CalibWire, message: &str, signal: &str, ours: Vec<(u8, &str)>) {
    let mut dbc = table(w, message, signal);
    dbc.sort_by_key(|(c, _)| *c);
    let ours: Vec<(i64, String)> = ours
        .into_iter()
        .map(|(c, n)| (i64::from(c), n.to_owned()))
        .collect();
    assert_eq!(dbc, ours, "{message}.{signal}");
}

macro_rules! pairs {
    ($t:ty) => {
        <$t>::ALL
            .iter()
            .map(|v| (v.code(), v.name()))
            .collect::<Vec<_>>()
    };
}

#[test]
fn every_code_table_equals_the_dbc_value_table_and_round_trips() {
    let w = wire();
    same_table(&w, CMD, "CMD", pairs!(CmdCode));
    same_table(&w, STATUS, "LAST_CMD", pairs!(CmdCode));
    same_table(&w, STATUS, "STATE", pairs!(State));
    same_table(&w, STATUS, "INSTRUCTION", pairs!(InstructionCode));
    same_table(&w, STATUS, "DIRECTION", pairs!(WireDirection));
    same_table(&w, STATUS, "START_POINT", pairs!(StartPoint));
    same_table(&w, STATUS, "WRITEBACK", pairs!(Writeback));
    same_table(&w, STATUS, "REJECT_REASON", pairs!(Reason));
    same_table(&w, STATUS, "CMD_REASON", pairs!(Reason));
    same_table(&w, ACK, "ACK_STATUS", pairs!(AckStatus));
    for c in 0..=255u8 {
        if let Some(r) = Reason::from_code(c) {
            assert_eq!(r.code(), c);
        }
        if let Some(v) = CmdCode::from_code(c) {
            assert_eq!(v.code(), c);
        }
    }
}

#[test]
fn every_refusal_and_rejection_has_its_own_reason() {
    use canodom_calib::run::InputFault;
    let refusals = (1..=13u8).map(|c| {
        let r = Refusal::ALL[usize::from(c - 1)];
        assert_eq!(r.code(), c);
        let reason = Reason::of_refusal(r);
        assert_eq!(reason.code(), r.code());
        reason
    });
    let rejections = [
        Rejection::TooFewSamples { samples: 1 },
        Rejection::LengthOff {
            length_m: 1.0,
            expected_m: 2.0,
        },
        Rejection::TurnOff {
            total_turn_rad: 1.0,
            expected_rad: std::f64::consts::TAU,
        },
        Rejection::InputFault {
            count: 1,
            first_t_s: 0.0,
            first: InputFault::NonFinite,
        },
        Rejection::SteeringInconsistent {
            segment: 0,
            mean_angle_rad: 0.0,
            expected_rad: 0.1,
        },
    ]
    .map(|r| {
        let reason = Reason::of_rejection(&r);
        assert_eq!(reason.code(), 13 + r.code());
        reason
    });
    let all: Vec<Reason> = refusals.chain(rejections).collect();
    let distinct: HashSet<Reason> = all.iter().copied().collect();
    assert_eq!(distinct.len(), 18);
    assert!(!distinct.contains(&Reason::None));
}

#[test]
fn states_and_instructions_follow_the_session_codes() {
    let phases = [
        Phase::Idle,
        Phase::Positioning,
        Phase::Recording,
        Phase::AwaitingEndPose,
        Phase::Ready,
        Phase::Computing,
        Phase::Computed,
    ];
    for (i, p) in phases.into_iter().enumerate() {
        assert_eq!(usize::from(State::of(p).code()), i);
    }
    let d = Direction::Cw;
    for ins in [
        Instruction::Idle,
        Instruction::RefitSteering,
        Instruction::GoToStart {
            run: 1,
            runs: 5,
            direction: d,
        },
        Instruction::Go {
            run: 1,
            runs: 5,
            direction: d,
        },
        Instruction::Drive {
            run: 1,
            runs: 5,
            direction: d,
        },
        Instruction::Stop { run: 1, runs: 5 },
        Instruction::MeasureEndPose { run: 1 },
        Instruction::ReadyToCompute,
        Instruction::Wait,
        Instruction::ReviewResult,
    ] {
        assert_eq!(InstructionCode::of(&ins).code(), ins.code());
    }
    for d in [None, Some(Direction::Cw), Some(Direction::Ccw)] {
        assert_eq!(WireDirection::of(d).direction(), d);
    }
}

#[test]
fn every_command_round_trips_with_counter_and_crc() {
    let w = wire();
    let cmds = [
        Command::StartSession {
            track_radius_mm: 780,
            runs_per_direction: 5,
        },
        Command::StartSession {
            track_radius_mm: 65_535,
            runs_per_direction: 0,
        },
        Command::StartSteering,
        Command::EndRun,
        Command::EndPose {
            dx_mm: -8192,
            dy_mm: 8191,
            dtheta_decideg: -2048,
        },
        Command::EndPose {
            dx_mm: 12,
            dy_mm: -340,
            dtheta_decideg: 57,
        },
        Command::Abort,
        Command::Compute,
        Command::Commit,
        Command::Rollback,
        Command::RequestParams,
        Command::StartRun,
    ];
    for (k, cmd) in cmds.into_iter().enumerate() {
        let counter = (k % 16) as u8;
        let data = w.encode_command(cmd, 0xA5, counter);
        let f = w.decode_command(&data).unwrap();
        assert!(f.checksum_ok);
        assert_eq!(f.command, Some(cmd));
        assert_eq!(f.cmd_raw, cmd.code().code());
        assert_eq!((f.arming_code, f.counter), (0xA5, counter));
        // cantools' view: the multiplexed arguments decode to the same values.
        let m = w.database().message_by_name(CMD).unwrap();
        let names: Vec<&str> = m.decode(&data).unwrap().map(|(s, _)| s.name()).collect();
        match cmd {
            Command::StartSession { .. } => assert!(names.contains(&"TRACK_RADIUS")),
            Command::EndPose { .. } => assert!(names.contains(&"END_DTHETA")),
            _ => assert!(!names.contains(&"TRACK_RADIUS")),
        }
        let mut bad = data;
        bad[7] ^= 1;
        assert!(!w.decode_command(&bad).unwrap().checksum_ok);
    }
    let undefined = w.encode_command_raw(14, Command::Abort, 0, 3);
    let f = w.decode_command(&undefined).unwrap();
    assert_eq!((f.cmd_raw, f.command), (14, None));
    assert!(w.decode_command(&[0; 7]).is_err());
}

#[test]
fn every_status_page_round_trips() {
    let w = wire();
    let pages = [
        StatusPage::Progress(Progress {
            state: State::Recording,
            instruction: InstructionCode::Drive,
            run_index: 3,
            runs_total: 5,
            direction: WireDirection::Cw,
            start_point: StartPoint::SCw,
            run_distance_m: 7.25,
            writeback: Writeback::Failed,
            standstill: true,
            writeback_attempts: 4,
            drift: true,
            drift_candidate: true,
        }),
        StatusPage::Counts(Counts {
            cw_accepted: 5,
            cw_rejected: 1,
            ccw_accepted: 4,
            ccw_rejected: 2,
            reject_reason: Reason::LengthOff,
            last_cmd: CmdCode::Commit.code(),
            cmd_reason: Reason::OutOfBounds,
            active_version: 65_535,
            cmd_seq: 6,
        }),
        StatusPage::ResultGeometry {
            rear_tread_m: 0.3101,
            rear_tread_std_m: 0.000_123,
            diameter_ratio: 1.015,
        },
        StatusPage::ResultQuality {
            diameter_ratio_std: 0.000_01,
            end_err_before_m: 0.529,
            end_err_after_m: 0.096,
        },
        StatusPage::ResultSteering {
            steer_gain: 0.98,
            steer_gain_std: 0.001,
            steer_offset_rad: -0.012,
        },
        StatusPage::ResultExtra {
            steer_offset_std_rad: 0.0005,
            version: 42,
        },
        StatusPage::Gnss(GnssStatus {
            source: GnssSourceKind::Nmea,
            connected: true,
            fixes_per_s: 1.0,
            error_95_m: Some(7.3),
            forwarded: 60_001,
            refused: 17,
            reconnects: 2,
        }),
        StatusPage::Gnss(GnssStatus {
            source: GnssSourceKind::Gpsd,
            connected: false,
            fixes_per_s: 0.0,
            error_95_m: None,
            forwarded: 0,
            refused: 255,
            reconnects: 3,
        }),
    ];
    for (k, page) in pages.iter().enumerate() {
        let data = w.encode_status(page, k as u8 + 9);
        let (back, counter) = w.decode_status(&data).unwrap();
        assert_eq!(counter, (k as u8 + 9) & 0x0F);
        assert_eq!(back.page(), page.page());
        close(&back, page);
        let mut bad = data;
        bad[2] ^= 0x10;
        assert!(matches!(
            w.decode_status(&bad),
            Err(WireError::BadChecksum { .. })
        ));
    }
    // Out-of-range values clamp rather than wrap.
    let huge = StatusPage::ResultQuality {
        diameter_ratio_std: 1.0,
        end_err_before_m: 1e6,
        end_err_after_m: f64::NAN,
    };
    let (back, _) = w.decode_status(&w.encode_status(&huge, 0)).unwrap();
    let StatusPage::ResultQuality {
        diameter_ratio_std,
        end_err_before_m,
        end_err_after_m,
    } = back
    else {
        panic!("page 3 expected")
    };
    assert!((diameter_ratio_std - 0.065_535).abs() < 1e-9);
    assert!((end_err_before_m - 65.535).abs() < 1e-9);
    assert_eq!(end_err_after_m, 0.0);
}

#[test]
fn the_gnss_page_saturates_and_never_reads_a_large_error_as_not_stated() {
    // A GNSS error beyond the signal's range reads as its top, never as
    // NOT_STATED; fixes per second beyond 25.5 saturate.
    let w = wire();
    let far = StatusPage::Gnss(GnssStatus {
        source: GnssSourceKind::Ros2,
        connected: true,
        fixes_per_s: 50.0,
        error_95_m: Some(1e4),
        forwarded: 1,
        refused: 0,
        reconnects: 9,
    });
    let (back, _) = w.decode_status(&w.encode_status(&far, 0)).unwrap();
    let StatusPage::Gnss(g) = back else {
        panic!("page 6 expected")
    };
    assert!((g.fixes_per_s - 25.5).abs() < 1e-9, "{g:?}");
    assert!(
        g.error_95_m.is_some_and(|e| (e - 409.4).abs() < 1e-9),
        "{g:?}"
    );
    assert_eq!((g.source, g.reconnects), (GnssSourceKind::Ros2, 3));
}

#[test]
fn the_gnss_source_codes_equal_the_dbc_value_table() {
    let w = wire();
    let ours: Vec<(u8, &str)> = [
        (GnssSourceKind::None, "NONE"),
        (GnssSourceKind::Gpsd, "GPSD"),
        (GnssSourceKind::Nmea, "NMEA"),
        (GnssSourceKind::Ros2, "ROS2"),
    ]
    .into_iter()
    .map(|(k, n)| {
        assert_eq!(GnssSourceKind::from_code(k.code()), k);
        (k.code(), n)
    })
    .collect();
    same_table(&w, STATUS, "GNSS_SOURCE", ours);
    assert_eq!(
        table(&w, STATUS, "GNSS_ERROR_95"),
        [(GNSS_ERROR_NOT_STATED as i64, "NOT_STATED".to_owned())]
    );
}

fn close(a: &StatusPage, b: &StatusPage) {
    let num = |p: &StatusPage| -> Vec<f64> {
        match *p {
            StatusPage::Progress(p) => vec![p.run_distance_m],
            StatusPage::Counts(_) => vec![],
            StatusPage::ResultGeometry {
                rear_tread_m,
                rear_tread_std_m,
                diameter_ratio,
            } => vec![rear_tread_m, rear_tread_std_m, diameter_ratio],
            StatusPage::ResultQuality {
                diameter_ratio_std,
                end_err_before_m,
                end_err_after_m,
            } => vec![diameter_ratio_std, end_err_before_m, end_err_after_m],
            StatusPage::ResultSteering {
                steer_gain,
                steer_gain_std,
                steer_offset_rad,
            } => vec![steer_gain, steer_gain_std, steer_offset_rad],
            StatusPage::ResultExtra {
                steer_offset_std_rad,
                ..
            } => vec![steer_offset_std_rad],
            StatusPage::Gnss(g) => vec![g.fixes_per_s, g.error_95_m.unwrap_or(-1.0)],
        }
    };
    for (x, y) in num(a).into_iter().zip(num(b)) {
        assert!((x - y).abs() < 1e-4 * y.abs().max(0.01), "{a:?} vs {b:?}");
    }
    match (a, b) {
        (StatusPage::Progress(x), StatusPage::Progress(y)) => {
            assert_eq!(
                Progress {
                    run_distance_m: 0.0,
                    ..*x
                },
                Progress {
                    run_distance_m: 0.0,
                    ..*y
                }
            );
        }
        (StatusPage::Counts(x), StatusPage::Counts(y)) => assert_eq!(x, y),
        (
            StatusPage::ResultExtra { version: x, .. },
            StatusPage::ResultExtra { version: y, .. },
        ) => assert_eq!(x, y),
        (StatusPage::Gnss(x), StatusPage::Gnss(y)) => assert_eq!(
            GnssStatus {
                fixes_per_s: 0.0,
                error_95_m: x.error_95_m.map(|_| 0.0),
                ..*x
            },
            GnssStatus {
                fixes_per_s: 0.0,
                error_95_m: y.error_95_m.map(|_| 0.0),
                ..*y
            }
        ),
        _ => {}
    }
}

fn set() -> ParamSet {
    ParamSet {
        version: 7,
        rear_tread_m: 0.3102,
        rear_left_diameter_m: 0.08944,
        rear_right_diameter_m: 0.09078,
        diameter_ratio: 1.01498,
        steer_gain: 0.98765,
        steer_offset_rad: -0.01234,
    }
}

#[test]
fn params_round_trip_through_the_assembler_and_a_corrupt_set_crc_is_caught() {
    let w = wire();
    let pages = w.encode_params(&set(), 14).unwrap();
    let mut asm = ParamsAssembler::default();
    let mut out = None;
    for (i, p) in pages.iter().enumerate() {
        let (page, counter) = w.decode_params(p).unwrap();
        assert_eq!(counter, (14 + i as u8) & 0x0F);
        assert_eq!(page.version, 7);
        out = asm.push(&w, page);
        assert_eq!(out.is_some(), i == 3);
    }
    let got = out.unwrap().unwrap();
    let want = set();
    for (g, e) in [
        (got.rear_tread_m, want.rear_tread_m),
        (got.rear_left_diameter_m, want.rear_left_diameter_m),
        (got.rear_right_diameter_m, want.rear_right_diameter_m),
        (got.diameter_ratio, want.diameter_ratio),
        (got.steer_gain, want.steer_gain),
        (got.steer_offset_rad, want.steer_offset_rad),
    ] {
        assert!((g - e).abs() < 2e-5, "{g} vs {e}");
    }
    // A page whose value changed but whose SET_CRC did not: caught.
    let mut p0 = pages[0];
    w.params[2].encode_raw(3202, &mut p0);
    let p0 = w.seal(2, 0, p0);
    let mut asm = ParamsAssembler::default();
    let mut last = None;
    for p in [p0, pages[1], pages[2], pages[3]] {
        last = asm.push(&w, w.decode_params(&p).unwrap().0);
    }
    assert!(last.unwrap().is_err(), "changed tread, old SET_CRC");
    // Corrupt SET_CRC itself.
    let mut asm = ParamsAssembler::default();
    let crc_h = w.params[8];
    let mut p0 = pages[0];
    crc_h.encode_raw(u64::from(w.set_crc(&want).unwrap() ^ 1), &mut p0);
    let p0 = w.seal(2, 0, p0);
    let mut last = None;
    for p in [p0, pages[1], pages[2], pages[3]] {
        last = asm.push(&w, w.decode_params(&p).unwrap().0);
    }
    assert!(last.unwrap().is_err());
    // Unrepresentable values are an error, not a wrap.
    let mut absurd = want;
    absurd.rear_tread_m = 9.0;
    assert!(matches!(
        w.encode_params(&absurd, 0),
        Err(WireError::OutOfRange { .. })
    ));
}

#[test]
fn set_crc_matches_the_documented_algorithm() {
    // CRC-16/CCITT-FALSE check value of "123456789" (the catalogue's).
    let crc = crc::Crc::<u16>::new(&crc::CRC_16_IBM_3740);
    assert_eq!(crc.checksum(b"123456789"), 0x29B1);
    let w = wire();
    let s = set();
    let raws = w.param_raws(&s).unwrap();
    let bytes: Vec<u8> = raws
        .iter()
        .flat_map(|r| (*r as u16).to_le_bytes())
        .collect();
    assert_eq!(w.set_crc(&s).unwrap(), crc.checksum(&bytes));
    assert_eq!(raws[1], 3102);
}

#[test]
fn ack_round_trips() {
    let w = wire();
    for (v, st, crc) in [
        (0u16, AckStatus::Stored, 0u16),
        (65_535, AckStatus::Refused, 0xBEEF),
        (7, AckStatus::Stored, 0xFFFF),
    ] {
        let data = w.encode_ack(
            Ack {
                version: v,
                status: st,
                set_crc: crc,
            },
            5,
        );
        let (ack, c) = w.decode_ack(&data).unwrap();
        assert_eq!((ack.version, ack.status, ack.set_crc, c), (v, st, crc, 5));
    }
    let mut data = w.encode_ack(
        Ack {
            version: 1,
            status: AckStatus::Stored,
            set_crc: 0,
        },
        0,
    );
    data[0] ^= 1;
    assert!(w.decode_ack(&data).is_err());
    let ext = CalibWire::new(BaseId::new(0x18FF_0000, true).unwrap()).unwrap();
    assert_eq!(ext.ack_id(), FrameId::Extended(0x18FF_0013));
    assert_eq!(wire().cmd_id(), FrameId::Standard(0x610));
}
