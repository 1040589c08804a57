"""Bad input through Python: each a clear exception naming what is at fault."""

import pytest

import canodom
from conftest import DATA, RAV4


def test_a_missing_log_is_file_not_found_naming_it(tmp_path):
    missing = tmp_path / "nowhere.log"
    with pytest.raises(FileNotFoundError, match="nowhere.log"):
        canodom.read_log(missing)
    with pytest.raises(FileNotFoundError, match="nowhere.log"):
        canodom.replay(missing, RAV4 / "config.toml")


def test_a_foreign_format_is_named_with_the_way_forward(tmp_path):
    csv = tmp_path / "drive.csv"
    csv.write_text("timestamp,arbitration_id,extended,remote,error,dlc,data\n"
                   "1700000000.0,0x123,0,0,0,2,0102\n")
    with pytest.raises(canodom.LogError, match=r"drive\.csv.*python-can CSV"):
        canodom.read_log(csv)
    with pytest.raises(canodom.LogError, match="python-can CSV"):
        canodom.decode(csv, DATA / "dbc" / "rc_car.dbc")


def test_a_dbc_with_a_bad_message_is_refused_under_strict(tmp_path):
    bad = tmp_path / "bad.dbc"
    text = (DATA / "dbc" / "rc_car.dbc").read_text()
    # A signal past its message's end: the message cannot be decoded.
    broken = 'BO_ 1999 BROKEN: 2 Vector__XXX\n SG_ TOO_FAR : 40|16@1+ (1,0) [0|0] "" Vector__XXX\n\n'
    at = text.index("\nBO_ ") + 1
    bad.write_text(text[:at] + broken + text[at:])
    with pytest.raises(canodom.DbcError, match="BROKEN"):
        canodom.decode(RAV4 / "drive.log", bad, strict=True)


def test_a_config_with_a_typo_names_file_line_and_key(tmp_path):
    config = tmp_path / "car.toml"
    text = (RAV4 / "config.toml").read_text().replace("wheelbase_m", "wheelbase_mm")
    text = text.replace('"../dbc/', f'"{DATA}/dbc/')
    config.write_text(text)
    with pytest.raises(canodom.ConfigError, match=r"(?s)car\.toml.*line 6.*wheelbase_mm"):
        canodom.replay(RAV4 / "drive.log", config)


def test_exceptions_are_canodom_errors():
    assert issubclass(canodom.LogError, canodom.CanodomError)
    assert issubclass(canodom.ConfigError, canodom.CanodomError)
