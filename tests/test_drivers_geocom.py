"""GeoCOM protocol: CRC-16 vectors, framing, return-code table and typed errors."""
from __future__ import annotations

import pytest
from hypothesis import given, settings, strategies as st

from drivers import geocom as gc


def test_crc16_published_vectors():
    assert gc.crc16("123456789") == 0xBB3D  # CRC-16/ARC check value
    assert gc.crc16("%R1P,0,11:0") == 22896  # GeoComPy docs: reply %R1P,0,11,22896:0
    assert gc.crc16("%R1Q,0,11:") == 28925


def _crc16_bitwise(data: bytes) -> int:
    crc = 0
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


@given(st.binary(max_size=64))
@settings(max_examples=40, deadline=None)
def test_crc16_table_equals_bitwise(data):
    assert gc.crc16(data) == _crc16_bitwise(data)


def test_request_framing_exact():
    assert gc.encode_request(0) == b"%R1Q,0:\r\n"
    assert gc.encode_request(2008, (1, 1), trid=7) == b"%R1Q,2008,7:1,1\r\n"
    assert gc.encode_request(0, (), trid=11, with_crc=True) == b"%R1Q,0,11,28925:\r\n"
    r = gc.decode_request("%R1Q,9037,5,9310:0.0873,0.0873,0")
    assert r.rpc == 9037 and r.trid == 5 and r.crc_ok and r.params == (0.0873, 0.0873, 0)
    assert not gc.decode_request("%R1Q,9037,5,9311:0.0873,0.0873,0").crc_ok


def test_reply_decode_and_crc_check():
    r = gc.decode_reply("%R1P,0,11,22896:0")
    assert (r.com_rc, r.trid, r.rc, r.params, r.crc_present) == (0, 11, 0, (), True)
    with pytest.raises(gc.GeoComChecksumError) as e:
        gc.decode_reply("%R1P,0,11,22897:0")
    assert e.value.code == 3102
    r = gc.decode_reply("%R1P,0,0:0,1996,'07','19','10','13','2f'")  # manual's CSV_GetDateTime
    assert r.params == (1996, 7, 0x19, 0x10, 0x13, 0x2F)
    r = gc.decode_reply('%R1P,0,3:0,"TS30",1.5')
    assert r.params == ("TS30", 1.5)
    assert gc.decode_reply("%R1P,3081,4:").rc == 3081
    with pytest.raises(gc.GeoComProtocolError):
        gc.decode_reply("%R1P,0,x:0")


@given(st.integers(0, 65535), st.integers(0, 32767), st.booleans(),
       st.lists(st.one_of(st.integers(-10**9, 10**9), st.floats(-1e6, 1e6, allow_nan=False)), max_size=6))
@settings(max_examples=40, deadline=None)
def test_reply_roundtrip(rc, trid, crc, params):
    line = gc.encode_reply(rc, params, trid, with_crc=crc).decode().rstrip("\r\n")
    r = gc.decode_reply(line)
    assert (r.rc, r.trid, r.crc_present) == (rc, trid, crc)
    assert list(r.params) == params


def test_every_return_code_has_name_sentence_and_type():
    for code, (name, text) in gc.RETURN_CODES.items():
        e = gc.error_for(code, rpc=2108)
        assert e.code == code and e.name == name and e.text == text
        assert name in str(e) and str(code) in str(e) and text.endswith(".")
    assert isinstance(gc.error_for(8710), gc.GeoComNoTarget)
    assert isinstance(gc.error_for(8725), gc.GeoComNotLocked)
    assert isinstance(gc.error_for(3077), gc.GeoComTimeout)
    assert isinstance(gc.error_for(13), gc.GeoComBusy)
    assert isinstance(gc.error_for(800), gc.GeoComMeasurementError)
    assert gc.error_for(8710).retryable and gc.error_for(1293).retryable
    assert not gc.error_for(2).retryable and not gc.error_for(1285).retryable
    assert gc.code_name(12345) == "GRC_UNKNOWN_12345"


@given(st.floats(allow_nan=False, allow_infinity=False))
@settings(max_examples=200, deadline=None)
def test_float_parameters_positional_and_exact(v):
    s = gc.format_param(v)
    assert "e" not in s.lower() and float(s) == v  # no exponent form; reads back bit for bit
    assert gc.parse_param(s) == v


def test_float_parameter_hand_cases():
    assert gc.format_param(1e-05) == "0.00001" and gc.format_param(-2.5e-7) == "-0.00000025"
    assert gc.format_param(0.0873) == "0.0873" and gc.format_param(1e16) == "10000000000000000.0"
    assert gc.encode_request(9037, (1e-6, 0.0873, 0), trid=2) == b"%R1Q,9037,2:0.000001,0.0873,0\r\n"
    with pytest.raises(ValueError, match="finite"):
        gc.format_param(float("nan"))


def test_reply_without_transaction_id():
    r = gc.decode_reply("%R1P,0:0")
    assert (r.com_rc, r.trid, r.rc, r.params, r.crc_present) == (0, None, 0, (), False)
    r = gc.decode_reply("%R1P,0:0,1.25,2")
    assert (r.trid, r.params) == (None, (1.25, 2))
    assert gc.encode_reply(0, (1.25, 2), None) == b"%R1P,0:0,1.25,2\r\n"
    with pytest.raises(gc.GeoComProtocolError):
        gc.decode_reply("%R1P,0,:0")


def test_ata_loader_codes_named_as_in_the_tps1200_manual():
    assert [gc.code_name(c) for c in (531, 532, 533, 534)] == [
        "GRC_ATA_SLDR_TRANSFER_PENDING", "GRC_ATA_SLDR_TRANSFER_ILLEGAL",
        "GRC_ATA_SLDR_DATA_ERROR", "GRC_ATA_SLDR_CHK_SUM_ERROR"]
    assert gc.code_name(526) == "GRC_ATA_DECODE_ERROR"


def test_reply_with_escaped_quotes_and_hexadecimal_integers():
    # an instrument name carrying a double quote, as a TS16 writes it, and a hex integer
    r = gc.decode_reply('%R1P,0,0:0,"TS16 A 1\\" R500",0x3AA,\'1F\',"a,b"')
    assert r.params == ('TS16 A 1" R500', 0x3AA, 0x1F, "a,b")
    r = gc.decode_reply('%R1P,0,0:0,"back\\\\slash",-0x10')
    assert r.params == ("back\\slash", -16)
    with pytest.raises(gc.GeoComProtocolError):
        gc.decode_reply('%R1P,0,0:0,"open,1')


@given(st.text(alphabet=st.characters(min_codepoint=32, max_codepoint=126), max_size=30))
@settings(max_examples=200, deadline=None)
def test_string_parameters_round_trip_through_a_reply(text):
    line = gc.encode_reply(0, (text, 7)).decode("ascii").rstrip("\r\n")
    assert gc.decode_reply(line).params == (text, 7)
