"""``trolley export --design / --design-name`` against another design than the track was processed
with: the deviations are the measured points' offsets from the design given, taken at their feet on
it, never track.csv's from another design beside another design's columns (bug hunt 2026-11-26:
the sheet showed one design's columns beside another's deviations and said PASS)."""
from __future__ import annotations

import json

import pandas as pd
import pytest
from typer.testing import CliRunner

from survey.cli import app

TWO_TRACKS = """<?xml version="1.0" encoding="UTF-8"?>
<LandXML xmlns="http://www.landxml.org/schema/LandXML-1.2" date="2024-05-02" time="10:11:12" version="1.2">
  <Units><Metric areaUnit="squareMeter" linearUnit="meter" volumeUnit="cubicMeter" temperatureUnit="celsius"
   pressureUnit="HPA"/></Units>
  <Alignments name="Site">
    <Alignment name="Track 1" length="500.0" staStart="START">
      <CoordGeom><Line staStart="START" length="500.0"><Start>1000.0 2000.0</Start><End>1000.0 2500.0</End></Line>
      </CoordGeom>
      <Profile name="P"><ProfAlign name="FG"><PVI>START 100</PVI><PVI>END 105</PVI></ProfAlign></Profile>
    </Alignment>
    <Alignment name="Track 2" length="500.0" staStart="START">
      <CoordGeom><Line staStart="START" length="500.0"><Start>1004.5 2000.0</Start><End>1004.5 2500.0</End></Line>
      </CoordGeom>
      <Profile name="P"><ProfAlign name="FG"><PVI>START 100.2</PVI><PVI>END 105.2</PVI></ProfAlign></Profile>
    </Alignment>
  </Alignments>
</LandXML>
"""


def _design(tmp_path, start=0.0, name="two.xml"):
    path = tmp_path / name
    path.write_text(TWO_TRACKS.replace("START", f"{start:g}").replace("END", f"{start + 500:g}"), encoding="utf-8")
    return path


def _track(tmp_path, first_m=0.0, last_m=500.0):
    """A track processed against Track 1 (eastwards along N = 1000): 3 mm right, 2 mm above it."""
    rows = ["chainage_m,E_m,N_m,H_m,sigma_E_mm,sigma_N_mm,sigma_H_mm,lateral_dev_mm,vertical_dev_mm,gauge_mm,"
            "cant_mm,twist_mm"]
    n = int(round((last_m - first_m) / 0.625))
    for i in range(n + 1):
        s = first_m + i * 0.625
        rows.append(f"{s:.3f},{2000 + s:.4f},999.9970,{100 + 0.01 * s + 0.002:.4f},0.5,0.5,0.5,3.0,2.0,1435.2,0.0,0.0")
    path = tmp_path / "track.csv"
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path


def _export(tmp_path, track, design, *extra, out="out.csv"):
    res = CliRunner().invoke(app, ["export", str(track), "--design", str(design), "--csv", str(tmp_path / out),
                                   "--json", *extra])
    return res, (json.loads(res.stdout) if res.exit_code == 0 else None)


def test_the_track_processed_against_track_1_checked_against_track_2_fails_by_its_real_offsets(tmp_path):
    track, design = _track(tmp_path), _design(tmp_path)
    res, summary = _export(tmp_path, track, design, "--design-name", "Track 2")
    assert res.exit_code == 0, res.output
    df = pd.read_csv(tmp_path / "out.csv")
    # by hand: Track 2 lies 4.5 m left of Track 1 and 0.2 m above it
    assert df["lateral_dev_mm"].to_numpy() == pytest.approx(4503.0, abs=0.01)
    assert df["vertical_dev_mm"].to_numpy() == pytest.approx(-198.0, abs=0.06)   # (H written to 0.1 mm)
    assert (df["design_N_m"] == 1004.5).all()
    assert summary["passed"] is False and summary["defects"] > 0
    assert any("lateral deviations from this design differ from track.csv's by up to 4500.0 mm" in n
               for n in summary["notes"])
    # against its own design the engine's deviations are kept as they are and nothing is noted
    res, summary = _export(tmp_path, track, design, "--design-name", "Track 1", out="own.csv")
    df = pd.read_csv(tmp_path / "own.csv")
    assert (df["lateral_dev_mm"] == 3.0).all() and (df["vertical_dev_mm"] == 2.0).all()
    assert summary["passed"] is True and not any("differ" in n or "stationing" in n for n in summary["notes"])


def test_a_design_on_other_stations_is_compared_at_the_feet_not_at_the_same_numbers(tmp_path):
    # the design's stationing starts at 1000; the track's chainages run 0-500: each point is
    # compared with the design where it lies, 1000 m further in the design's numbers
    track, design = _track(tmp_path), _design(tmp_path, start=1000.0)
    res, summary = _export(tmp_path, track, design, "--design-name", "Track 1")
    assert res.exit_code == 0, res.output
    df = pd.read_csv(tmp_path / "out.csv")
    row = df[df["chainage_m"] == 250.0].iloc[0]
    assert (row["design_E_m"], row["design_N_m"], row["lateral_dev_mm"]) == (2250.0, 1000.0, 3.0)
    assert row["design_H_m"] == pytest.approx(102.5) and row["vertical_dev_mm"] == pytest.approx(2.0, abs=1e-6)
    assert any("not this design's stationing (the station at 0.000 m lies at the design's 1000.000 m" in n
               for n in summary["notes"])


def test_stations_beyond_the_designs_ends_are_empty_and_a_track_wholly_beyond_is_refused(tmp_path):
    # the track runs 400-600 m along Track 1, which ends at 500 m
    track, design = _track(tmp_path, 400.0, 600.0), _design(tmp_path)
    res, summary = _export(tmp_path, track, design, "--design-name", "Track 1")
    assert res.exit_code == 0, res.output
    df = pd.read_csv(tmp_path / "out.csv")
    beyond = df["chainage_m"] > 500.0 + 0.005
    assert beyond.sum() == 160 and df.loc[beyond, ["design_E_m", "lateral_dev_mm"]].isna().all().all()
    assert (df.loc[~beyond, "lateral_dev_mm"] == 3.0).all()
    assert any("160 station(s) at chainage 500.625-600.000 m lie beyond the ends of the design" in n
               for n in summary["notes"])
    track = _track(tmp_path, 600.0, 700.0)
    res, _ = _export(tmp_path, track, design, "--design-name", "Track 1", out="none.csv")
    assert res.exit_code == 2 and "lies wholly beyond the ends of this design (0.000-500.000 m)" in res.stderr
    assert not (tmp_path / "none.csv").exists()


@pytest.mark.parametrize("encoding", ["iso-8859-1", "utf-16", "utf-8-sig"])
def test_a_design_in_the_encoding_its_xml_declaration_names_is_read(tmp_path, encoding):
    # (bug hunt 2026-11-26) valid XML declared ISO-8859-1, or UTF-16 with its mark, was refused as
    # "not UTF-8"; the project store keeps it as UTF-8 text that says so
    from survey.store import alignment_record_from_text
    from trolley.landxml import LandXmlError, decoded_landxml

    xml = TWO_TRACKS.replace("START", "0").replace("END", "500").replace("Track 2", "Gleis Süd")
    if encoding == "iso-8859-1":
        xml = xml.replace('encoding="UTF-8"', 'encoding="ISO-8859-1"')
    (tmp_path / "d.xml").write_bytes(xml.encode(encoding))
    res, summary = _export(tmp_path, _track(tmp_path), tmp_path / "d.xml", "--design-name", "Gleis Süd")
    assert res.exit_code == 0, res.output
    assert pd.read_csv(tmp_path / "out.csv")["lateral_dev_mm"].to_numpy() == pytest.approx(4503.0, abs=0.01)
    text = decoded_landxml((tmp_path / "d.xml").read_bytes())
    assert text.startswith('<?xml version="1.0" encoding="UTF-8"?>') and "Gleis Süd" in text
    assert alignment_record_from_text("d.xml", text, 1.5, "Gleis Süd").name == "Gleis Süd"
    with pytest.raises(LandXmlError, match="not valid UTF-8 text"):
        decoded_landxml(xml.replace('encoding="ISO-8859-1"', 'encoding="UTF-8"').encode("iso-8859-1"))
    with pytest.raises(LandXmlError, match="unknown encoding 'klingon'"):
        decoded_landxml(b'<?xml version="1.0" encoding="klingon"?><LandXML/>')
