"""LandXML ``<CoordinateSystem>``: what a design file says about its CRS and datums."""
from __future__ import annotations

import pytest

from trolley.landxml import CoordinateSystemInfo, LandXmlError, coordinate_system

HEAD = ('<LandXML xmlns="http://www.landxml.org/schema/LandXML-1.2" date="2024-01-01" time="00:00:00" '
        'version="1.2"><Units><Metric areaUnit="squareMeter" linearUnit="meter" volumeUnit="cubicMeter" '
        'temperatureUnit="celsius" pressureUnit="HPA"/></Units>{}</LandXML>')


def test_epsg_code_and_datums():
    cs = coordinate_system(HEAD.format(
        '<CoordinateSystem name="ETRS89 / UTM zone 32N" epsgCode="25832" horizontalDatum="ETRS89" '
        'verticalDatum="DHHN2016" verticalCoordinateSystemName="DHHN2016 height"/>'))
    assert cs == CoordinateSystemInfo(name="ETRS89 / UTM zone 32N", epsg_code=25832, horizontal_datum="ETRS89",
                                      vertical_datum="DHHN2016", vertical_crs_name="DHHN2016 height")
    assert cs.crs_text == "EPSG:25832"


@pytest.mark.parametrize("code", ["EPSG:3067", "urn:ogc:def:crs:EPSG::3067", " 3067 "])
def test_epsg_code_spellings(code):
    assert coordinate_system(HEAD.format(f'<CoordinateSystem epsgCode="{code}"/>')).epsg_code == 3067


def test_wkt_and_proj_string():
    wkt = 'PROJCS["ETRS89 / TM35FIN(E,N)",GEOGCS["ETRS89"]]'
    cs = coordinate_system(HEAD.format(f"<CoordinateSystem ogcWktCode='{wkt}'/>"))
    assert cs.ogc_wkt == wkt and cs.proj4 is None and cs.crs_text == wkt
    proj = "+proj=utm +zone=35 +ellps=GRS80 +units=m"
    cs = coordinate_system(HEAD.format(f'<CoordinateSystem ogcWktCode="{proj}"/>'))
    assert cs.proj4 == proj and cs.ogc_wkt is None and cs.crs_text == proj


def test_absent_and_bad():
    assert coordinate_system(HEAD.format("")) is None
    with pytest.raises(LandXmlError, match="epsgCode='UTM32'"):
        coordinate_system(HEAD.format('<CoordinateSystem epsgCode="UTM32"/>'))
    with pytest.raises(LandXmlError, match="not well-formed"):
        coordinate_system("<LandXML>")
