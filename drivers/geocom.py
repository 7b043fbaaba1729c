"""Leica GeoCOM ASCII protocol: framing, CRC-16, parameter types, return codes, typed errors.

Every GeoCOM constant of this project lives here (protocols.md section 1, from the TPS1100 and
TPS1200/TS30 GeoCOM reference manuals, GeoComPy and DMPACK):

    request  [<LF>]%R1Q,<RPC>[,<TrId>[,<CRC>]]:[<P0>][,<P1>,...]<CR><LF>
    reply    %R1P,<RC_COM>[,<TrId>[,<CRC>]]:<RC>[,<P0>,<P1>,...]<CR><LF>

CRC-16/ARC (poly 0xA001 reflected, init 0, no final XOR) over the message without its CRC field
and without the terminator. Values are SI (m, rad); strings in double quotes; bytes as 'hh'.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from decimal import Decimal

TERMINATOR = b"\r\n"
CLEAR_BUFFER = b"\n"
MAX_TRID = 32767

# ------------------------------------------------------------------ RPC numbers (section 1.5)
COM_NULLPROC = 0
COM_GETSWVERSION = 110
COM_GETDOUBLEPRECISION = 108
COM_SETDOUBLEPRECISION = 107
CSV_GETINSTRUMENTNAME = 5004
CSV_GETINSTRUMENTNO = 5003
CSV_GETSWVERSION = 5034
TMC_DOMEASURE = 2008
TMC_GETCOORDINATE = 2082
TMC_GETSIMPLEMEA = 2108
TMC_GETSIMPLECOORD = 2116
TMC_GETANGLE = 2003
TMC_GETANGLE5 = 2107
TMC_SETSTATION = 2010
TMC_GETSTATION = 2009
TMC_SETORIENTATION = 2113
TMC_SETHEIGHT = 2012
TMC_GETHEIGHT = 2011
TMC_SETPRISMCORR = 2024
TMC_GETPRISMCORR = 2023
BAP_MEASDISTANCEANGLE = 17017
BAP_SETPRISMTYPE = 17008
AUT_FINEADJUST = 9037
AUT_MAKEPOSITIONING = 9027
AUT_LOCKIN = 9013
AUS_SETUSERATRSTATE = 18005
AUS_SETUSERLOCKSTATE = 18007
AUS_GETUSERLOCKSTATE = 18008
MOT_READLOCKSTATUS = 6021

# enums
TMC_STOP, TMC_DEF_DIST, TMC_TRK_DIST, TMC_CLEAR, TMC_RTRK_DIST = 0, 1, 2, 3, 8
TMC_MEA_INC, TMC_AUTO_INC, TMC_PLANE_INC = 0, 1, 2
BAP_NO_MEAS, BAP_NO_DIST, BAP_DEF_DIST = 0, 1, 2
#: BAP_PRISMTYPE (dmpack ``dm_geocom_type.f90``, GeoComPy ``gcdata.py``; protocols.md 1.5)
BAP_PRISM_ROUND, BAP_PRISM_MINI, BAP_PRISM_TAPE, BAP_PRISM_360 = 0, 1, 2, 3
BAP_PRISM_360_MINI, BAP_PRISM_MINI_ZERO = 7, 8

# ------------------------------------------------------------------ prism constants
#: Leica's additive prism constants (the "Leica constant", relative to the round prism, which is
#: 0.0 mm by definition), m, of the prism types BAP_SetPrismType selects. The instrument adds the
#: constant to the distance its EDM measured, so a prism whose reflection point lies further behind
#: its reference point than the round prism's gets a positive constant. The absolute constant
#: (other makers' convention, a correction from the prism's optical reversal point to its centre)
#: is the Leica constant - 34.4 mm: round -34.4, 360° -11.3 mm.
#: Sources (secondary; not read in a Leica manual): Bohnenstingl, "Prism constants" (round 0.0 by
#: definition, 360° GRZ121 +23.1 mm, absolute = Leica - 34.4 mm; scribd.com/document/375880904);
#: surveyorinsider.com/leica-prism-constants (round GPR1 0.0, mini GMP101 +17.5, tape +34.4,
#: 360° GRZ4/GRZ122 +23.1, mini 360° GRZ101 +17.5, mini 0 0.0 mm). The user types 4-6 and 9 (user
#: defined) and the newer types 10-12 have no constant listed there and are left out.
LEICA_PRISM_CONSTANT_M: dict[int, float] = {
    BAP_PRISM_ROUND: 0.0,
    BAP_PRISM_MINI: 0.0175,
    BAP_PRISM_TAPE: 0.0344,
    BAP_PRISM_360: 0.0231,
    BAP_PRISM_360_MINI: 0.0175,
    BAP_PRISM_MINI_ZERO: 0.0,
}

# ------------------------------------------------------------------ return codes (section 1.4)
GRC_OK = 0
#: code -> (name, human sentence)
RETURN_CODES: dict[int, tuple[str, str]] = {
    0: ("GRC_OK", "Function completed successfully."),
    1: ("GRC_UNDEFINED", "Unknown error, result unspecified."),
    2: ("GRC_IVPARAM", "Invalid parameter detected; result unspecified."),
    3: ("GRC_IVRESULT", "Invalid result."),
    4: ("GRC_FATAL", "Fatal error."),
    5: ("GRC_NOT_IMPL", "Not implemented (e.g. the instrument has no motor or ATR)."),
    6: ("GRC_TIME_OUT", "Function execution timed out; result unspecified."),
    7: ("GRC_SET_INCOMPL", "Parameter setup for subsystem is incomplete."),
    8: ("GRC_ABORT", "Function execution has been aborted."),
    9: ("GRC_NOMEMORY", "Fatal error: not enough memory."),
    10: ("GRC_NOTINIT", "Fatal error: subsystem not initialised."),
    12: ("GRC_SHUT_DOWN", "Subsystem is down."),
    13: ("GRC_SYSBUSY", "System busy or already in use; try again."),
    14: ("GRC_HWFAILURE", "Fatal error: hardware failure."),
    15: ("GRC_ABORT_APPL", "Execution of the application has been aborted."),
    16: ("GRC_LOW_POWER", "Operation aborted: insufficient power supply level."),
    17: ("GRC_IVVERSION", "Invalid version of file."),
    18: ("GRC_BATT_EMPTY", "Battery empty."),
    20: ("GRC_NO_EVENT", "No event pending."),
    21: ("GRC_OUT_OF_TEMP", "Out of temperature range."),
    22: ("GRC_INSTRUMENT_TILT", "Instrument tilt is out of range."),
    23: ("GRC_COM_SETTING", "Communication error."),
    24: ("GRC_NO_ACTION", "Recognised input, no action taken."),
    25: ("GRC_SLEEP_MODE", "Instrument went into sleep mode."),
    26: ("GRC_NOTOK", "Function not successfully completed."),
    27: ("GRC_NA", "Not available (licence key not available, e.g. GeoCOM robotic licence)."),
    28: ("GRC_OVERFLOW", "Overflow error."),
    29: ("GRC_STOPPED", "System or subsystem has been stopped."),
    512: ("GRC_ATA_NOT_READY", "ATR system is not ready."),
    513: ("GRC_ATA_NO_RESULT", "ATR: result is not available yet."),
    514: ("GRC_ATA_SEVERAL_TARGETS", "ATR: several targets detected."),
    515: ("GRC_ATA_BIG_SPOT", "ATR: spot is too big for analysis."),
    516: ("GRC_ATA_BACKGROUND", "ATR: background is too bright."),
    517: ("GRC_ATA_NO_TARGETS", "ATR: no targets detected."),
    518: ("GRC_ATA_NOT_ACCURAT", "ATR: accuracy worse than asked for."),
    519: ("GRC_ATA_SPOT_ON_EDGE", "ATR: spot is on the edge of the sensing area."),
    522: ("GRC_ATA_BLOOMING", "ATR: blooming or spot on edge detected."),
    523: ("GRC_ATA_NOT_BUSY", "ATR is not in a continuous mode."),
    524: ("GRC_ATA_STRANGE_LIGHT", "ATR: not the spot of its own target illumination."),
    525: ("GRC_ATA_V24_FAIL", "ATR: communication error to the sensor."),
    526: ("GRC_ATA_DECODE_ERROR", "ATR: received arguments cannot be decoded."),
    527: ("GRC_ATA_HZ_FAIL", "ATR: no spot detected in the Hz direction."),
    528: ("GRC_ATA_V_FAIL", "ATR: no spot detected in the V direction."),
    529: ("GRC_ATA_HZ_STRANGE_L", "ATR: strange light in the Hz direction."),
    530: ("GRC_ATA_V_STRANGE_L", "ATR: strange light in the V direction."),
    # 531-537: the ATR sensor's firmware loader (slider); names as in the TPS1200 GeoCOM manual
    531: ("GRC_ATA_SLDR_TRANSFER_PENDING", "ATR firmware loader: transfer already open (multiple OpenTransfer)."),
    532: ("GRC_ATA_SLDR_TRANSFER_ILLEGAL", "ATR firmware loader: no transfer open."),
    533: ("GRC_ATA_SLDR_DATA_ERROR", "ATR firmware loader: unexpected data format received."),
    534: ("GRC_ATA_SLDR_CHK_SUM_ERROR", "ATR firmware loader: checksum error in the transmitted data."),
    535: ("GRC_ATA_SLDR_ADDRESS_ERROR", "ATR firmware loader: address out of range."),
    536: ("GRC_ATA_SLDR_INV_LOADFILE", "ATR firmware loader: firmware file has an invalid format."),
    537: ("GRC_ATA_SLDR_UNSUPPORTED", "ATR firmware loader: the loaded firmware does not support upload."),
    538: ("GRC_ATA_PS_NOT_READY", "PowerSearch system is not ready."),
    539: ("GRC_ATA_ATR_SYSTEM_ERR", "ATR system error."),
    1283: ("GRC_TMC_NO_FULL_CORRECTION", "Warning: measurement without full correction; result usable (flag quality)."),
    1284: ("GRC_TMC_ACCURACY_GUARANTEE", "Info: accuracy cannot be guaranteed; result usable (flag quality)."),
    1285: ("GRC_TMC_ANGLE_OK", "Only the angles were measured, no distance."),
    1288: ("GRC_TMC_ANGLE_NO_FULL_CORRECTION", "Only angles, and not fully corrected."),
    1289: ("GRC_TMC_ANGLE_ACCURACY_GUARANTEE", "Only angles, accuracy cannot be guaranteed."),
    1290: ("GRC_TMC_ANGLE_ERROR", "No angle measurement possible."),
    1291: ("GRC_TMC_DIST_PPM", "Wrong setting of PPM or MM on the EDM."),
    1292: ("GRC_TMC_DIST_ERROR", "Distance measurement not done (no target or no aim)."),
    1293: ("GRC_TMC_BUSY", "TMC is busy, or a distance must be cleared before setting station/orientation."),
    1294: ("GRC_TMC_SIGNAL_ERROR", "No EDM signal (target not visible or too far)."),
    1792: ("GRC_MOT_UNREADY", "Motorisation is not ready."),
    1793: ("GRC_MOT_BUSY", "Motorisation is busy or in the wrong mode."),
    1794: ("GRC_MOT_NOT_OCONST", "Motorisation is not in velocity mode."),
    1795: ("GRC_MOT_NOT_CONFIG", "Motorisation is in the wrong mode or busy."),
    1796: ("GRC_MOT_NOT_POSIT", "Motorisation is not in posit mode."),
    1797: ("GRC_MOT_NOT_SERVICE", "Motorisation is not in service mode."),
    1798: ("GRC_MOT_NOT_BUSY", "Motorisation is handling no task."),
    1799: ("GRC_MOT_NOT_LOCK", "Motorisation is not in tracking (lock) mode."),
    1800: ("GRC_MOT_NOT_SPIRAL", "Motorisation is not in spiral mode."),
    3072: ("GRC_COM_ERO", "Initiate extended runtime operation (ERO)."),
    3073: ("GRC_COM_CANT_ENCODE", "Cannot encode the arguments in the client."),
    3074: ("GRC_COM_CANT_DECODE", "Cannot decode the results in the client."),
    3075: ("GRC_COM_CANT_SEND", "Hardware error while sending."),
    3076: ("GRC_COM_CANT_RECV", "Hardware error while receiving."),
    3077: ("GRC_COM_TIMEDOUT", "Request timed out (no reply from the instrument)."),
    3078: ("GRC_COM_WRONG_FORMAT", "Packet format error."),
    3079: ("GRC_COM_VER_MISMATCH", "Version mismatch between client and server."),
    3080: ("GRC_COM_CANT_DECODE_REQ", "The instrument could not decode the request."),
    3081: ("GRC_COM_PROC_UNAVAIL", "Unknown RPC: procedure not available on this firmware."),
    3082: ("GRC_COM_CANT_ENCODE_REP", "The instrument could not encode the reply."),
    3083: ("GRC_COM_SYSTEM_ERR", "Communication hardware error."),
    3085: ("GRC_COM_FAILED", "Unspecified communication failure."),
    3086: ("GRC_COM_NO_BINARY", "Binary protocol not available."),
    3087: ("GRC_COM_INTR", "Call interrupted."),
    3090: ("GRC_COM_REQUIRES_8DBITS", "Protocol needs 8 data bits."),
    3093: ("GRC_COM_TR_ID_MISMATCH", "Reply transaction id does not match the request."),
    3094: ("GRC_COM_NOT_GEOCOM", "Parse failed: data package is not GeoCOM."),
    3095: ("GRC_COM_UNKNOWN_PORT", "Unknown port."),
    3100: ("GRC_COM_OVERRUN", "Receive buffer overrun."),
    3101: ("GRC_COM_SRVR_RX_CHECKSUM_ERROR", "Instrument received a request with a bad checksum."),
    3102: ("GRC_COM_CLNT_RX_CHECKSUM_ERROR", "Client received a reply with a bad checksum."),
    3103: ("GRC_COM_PORT_NOT_AVAILABLE", "Port not available."),
    3104: ("GRC_COM_PORT_NOT_OPEN", "Port not opened."),
    3105: ("GRC_COM_NO_PARTNER", "Unable to find the instrument."),
    3106: ("GRC_COM_ERO_NOT_STARTED", "Extended runtime operation could not be started."),
    3107: ("GRC_COM_CONS_REQ", "Consecutive requests: the previous one is still running."),
    3108: ("GRC_COM_SRVR_IS_SLEEPING", "Instrument has gone to sleep; wake it up."),
    3109: ("GRC_COM_SRVR_IS_OFF", "Instrument has shut down."),
    3110: ("GRC_COM_NO_CHECKSUM", "No checksum in the message."),
    8704: ("GRC_AUT_TIMEOUT", "ATR: position not reached within the time limit."),
    8705: ("GRC_AUT_DETENT_ERROR", "Positioning not possible because of a mounted EDM."),
    8706: ("GRC_AUT_ANGLE_ERROR", "Angle measurement error."),
    8707: ("GRC_AUT_MOTOR_ERROR", "Motorisation error."),
    8708: ("GRC_AUT_INCACC", "Position not exactly reached."),
    8709: ("GRC_AUT_DEV_ERROR", "Deviation measurement error."),
    8710: ("GRC_AUT_NO_TARGET", "No target detected (no prism in the ATR field of view)."),
    8711: ("GRC_AUT_MULTIPLE_TARGETS", "Multiple targets detected."),
    8712: ("GRC_AUT_BAD_ENVIRONMENT", "Bad environmental conditions for ATR."),
    8713: ("GRC_AUT_DETECTOR_ERROR", "Error in target acquisition."),
    8714: ("GRC_AUT_NOT_ENABLED", "ATR or LOCK is not enabled."),
    8715: ("GRC_AUT_CALACC", "ATR calibration failed."),
    8716: ("GRC_AUT_ACCURACY", "Target position not exactly reached."),
    8717: ("GRC_AUT_DIST_STARTED", "Distance measurement has been started."),
    8718: ("GRC_AUT_SUPPLY_TOO_HIGH", "External supply voltage too high."),
    8719: ("GRC_AUT_SUPPLY_TOO_LOW", "Internal or external supply voltage too low."),
    8720: ("GRC_AUT_NO_WORKING_AREA", "Working area not set."),
    8721: ("GRC_AUT_ARRAY_FULL", "Power search data array is full."),
    8722: ("GRC_AUT_NO_DATA", "No data available."),
    8725: ("GRC_AUT_NO_LOCK", "ATR is not locked on the prism."),
    9217: ("GRC_BAP_CHANGE_ALL_TO_DIST", "No prism detected; the command was changed to distance only."),
}

#: codes after which TMC results are usable (flag quality) / only angles are valid
TMC_RESULT_USABLE = frozenset({0, 1283, 1284})
TMC_ANGLES_ONLY = frozenset({1285, 1288, 1289})
#: transient codes a client retries with back-off: timeouts, no target, not locked, busy,
#: checksum errors and a port that is momentarily gone (3075/3076, USB unplug)
RETRYABLE_CODES = frozenset({6, 13, 1292, 1293, 1294, 1793, 1799, 3075, 3076, 3077, 3078, 3101, 3110, 3102, 3107,
                             8704, 8710, 8725, 517})


def code_name(code: int) -> str:
    """Symbolic name of a GeoCOM return code (``GRC_EDM_<n>`` etc. for unlisted ones)."""
    if code in RETURN_CODES:
        return RETURN_CODES[code][0]
    if 769 <= code <= 832:
        return f"GRC_EDM_{code}"
    if 1792 <= code <= 1810:
        return f"GRC_MOT_{code}"
    return f"GRC_UNKNOWN_{code}"


def code_text(code: int) -> str:
    """Human sentence for a GeoCOM return code."""
    if code in RETURN_CODES:
        return RETURN_CODES[code][1]
    if 769 <= code <= 832:
        return f"EDM error {code} (texts differ between firmware generations)."
    return f"Return code {code} is not in the GeoCOM table of this software."


# ------------------------------------------------------------------ typed errors
class GeoComError(Exception):
    """A GeoCOM call failed. Carries the code, its name and a human sentence.

    Attributes
    ----------
    code : GeoCOM return code (RC, or RC_COM when the communication layer failed).
    name : symbolic name (``GRC_AUT_NO_TARGET``).
    text : human sentence.
    rpc : the RPC number that failed, when known.
    """

    def __init__(self, code: int, rpc: int | None = None, detail: str = "") -> None:
        self.code = int(code)
        self.name = code_name(self.code)
        self.text = code_text(self.code)
        self.rpc = rpc
        self.detail = detail
        where = f" (RPC {rpc})" if rpc is not None else ""
        extra = f": {detail}" if detail else ""
        super().__init__(f"GeoCOM {self.code} {self.name}{where}: {self.text}{extra}")

    @property
    def retryable(self) -> bool:
        """Whether the failure is transient (timeout, no target, not locked, busy)."""
        return self.code in RETRYABLE_CODES


class GeoComTimeout(GeoComError):
    """No (valid) reply in time, or the instrument reported a timeout."""


class GeoComNoTarget(GeoComError):
    """ATR found no prism."""


class GeoComNotLocked(GeoComError):
    """ATR is not locked on the prism."""


class GeoComBusy(GeoComError):
    """The instrument or a subsystem is busy."""


class GeoComChecksumError(GeoComError):
    """A reply (or request, as seen by the instrument) failed its CRC-16."""


class GeoComProtocolError(GeoComError):
    """A reply that is not GeoCOM, or a transaction id that does not match."""


class GeoComMeasurementError(GeoComError):
    """TMC/EDM/angle measurement failed."""


_ERROR_CLASS: dict[int, type[GeoComError]] = {
    6: GeoComTimeout, 3077: GeoComTimeout, 8704: GeoComTimeout,
    8710: GeoComNoTarget, 517: GeoComNoTarget,
    8725: GeoComNotLocked, 1799: GeoComNotLocked, 8714: GeoComNotLocked,
    13: GeoComBusy, 1293: GeoComBusy, 1793: GeoComBusy, 3107: GeoComBusy,
    3101: GeoComChecksumError, 3102: GeoComChecksumError, 3110: GeoComChecksumError,
    3074: GeoComProtocolError, 3078: GeoComProtocolError, 3093: GeoComProtocolError,
    3094: GeoComProtocolError,
    1285: GeoComMeasurementError, 1288: GeoComMeasurementError, 1289: GeoComMeasurementError,
    1290: GeoComMeasurementError, 1291: GeoComMeasurementError, 1292: GeoComMeasurementError,
    1294: GeoComMeasurementError,
}


def error_for(code: int, rpc: int | None = None, detail: str = "") -> GeoComError:
    """The typed exception for return code ``code``."""
    cls = _ERROR_CLASS.get(int(code))
    if cls is None and 769 <= code <= 832:
        cls = GeoComMeasurementError
    return (cls or GeoComError)(code, rpc, detail)


# ------------------------------------------------------------------ CRC-16/ARC
def _crc16_table() -> list[int]:
    out = []
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ 0xA001 if c & 1 else c >> 1
        out.append(c)
    return out


CRC16_TABLE = _crc16_table()


def crc16(data: bytes | str) -> int:
    """CRC-16/ARC (GeoCOM checksum): poly 0xA001 reflected, init 0, no final XOR."""
    if isinstance(data, str):
        data = data.encode("ascii")
    crc = 0
    for b in data:
        crc = CRC16_TABLE[(crc ^ b) & 0xFF] ^ (crc >> 8)
    return crc


# ------------------------------------------------------------------ parameters
def format_param(v: object) -> str:
    """One parameter in GeoCOM ASCII: bool -> 0/1, int, float (positional decimal with the
    shortest digits that read back exactly), str -> "quoted"."""
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"cannot encode GeoCOM parameter {v!r}: not a finite number")
        # shortest round-trip digits, never in exponent form (1e-05 -> 0.00001)
        s = format(Decimal(repr(v)), "f")
        return s if "." in s else s + ".0"  # always readable as a double, never as an integer
    if isinstance(v, str):
        # a double quote or backslash inside a string is escaped with a backslash, as the
        # instruments write them (e.g. an instrument name "TS16 A 1\" R500")
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (bytes, bytearray)) and len(v) == 1:
        return f"'{v[0]:02X}'"
    raise TypeError(f"cannot encode GeoCOM parameter {v!r}")


def parse_param(s: str) -> object:
    """Decode one ASCII parameter: "string" (backslash escapes \\" and \\\\ undone), 'hex byte',
    hexadecimal integer (``0x3AA``), decimal integer or float.

    Raises
    ------
    ValueError : none of these forms.
    """
    s = s.strip()
    if len(s) >= 2 and s[0] == s[-1] == '"':
        return _ESCAPE_RE.sub(lambda m: m.group(1), s[1:-1])
    if len(s) >= 2 and s[0] == s[-1] == "'":
        return int(s[1:-1], 16)
    if _HEX_RE.match(s):
        return int(s, 16)
    try:
        return int(s)
    except ValueError:
        return float(s)


_ESCAPE_RE = re.compile(r"\\(.)")
_HEX_RE = re.compile(r"^[+-]?0[xX][0-9a-fA-F]+$")


def split_params(s: str) -> list[str]:
    """Split on commas outside double quotes (a backslash-escaped quote does not end a string).

    Raises
    ------
    ValueError : a string is not closed.
    """
    if s == "":
        return []
    out, cur, q, esc = [], [], False, False
    for ch in s:  # parameter lists are a few dozen characters: a plain scan is the clearest
        if esc:
            esc = False
        elif q and ch == "\\":
            esc = True
        elif ch == '"':
            q = not q
        if ch == "," and not q:
            out.append("".join(cur))
            cur = []
        else:
            cur.append(ch)
    if q:
        raise ValueError(f"unterminated string in GeoCOM parameters {s[:60]!r}")
    out.append("".join(cur))
    return out


# ------------------------------------------------------------------ framing
@dataclass(frozen=True)
class Request:
    """A decoded request (as the instrument sees it)."""

    rpc: int
    trid: int | None
    params: tuple
    crc_present: bool
    crc_ok: bool


@dataclass(frozen=True)
class Reply:
    """A decoded reply.

    Attributes
    ----------
    com_rc : communication-layer return code (0 = OK).
    trid : transaction id echoed by the instrument (0 when the request had none); None when
        the reply has no transaction-id field (the manual's framing makes it optional).
    rc : return code of the RPC.
    params : decoded parameters after RC.
    crc_present : whether the reply carried a CRC field (already verified when present).
    t_host_s : host time the reply line completed.
    raw : the reply line without its terminator.
    """

    com_rc: int
    trid: int | None
    rc: int
    params: tuple
    crc_present: bool = False
    t_host_s: float = float("nan")
    raw: str = ""


def encode_request(rpc: int, params: tuple | list = (), trid: int | None = None,
                   with_crc: bool = False) -> bytes:
    """``%R1Q,<rpc>[,<trid>[,<crc>]]:<params>\\r\\n`` (no leading LF; the client adds it)."""
    body = ",".join(format_param(p) for p in params)
    if with_crc:
        if trid is None:
            trid = 0
        crc = crc16(f"%R1Q,{rpc},{trid}:{body}")
        msg = f"%R1Q,{rpc},{trid},{crc}:{body}"
    elif trid is not None:
        msg = f"%R1Q,{rpc},{trid}:{body}"
    else:
        msg = f"%R1Q,{rpc}:{body}"
    return msg.encode("ascii") + TERMINATOR


def encode_reply(rc: int, params: tuple | list = (), trid: int | None = 0, com_rc: int = 0,
                 with_crc: bool = False) -> bytes:
    """``%R1P,<com_rc>,<trid>[,<crc>]:<rc>[,<params>]\\r\\n`` (``trid=None`` without CRC: the
    short form ``%R1P,<com_rc>:<rc>...`` with no transaction id)."""
    body = ",".join([str(int(rc))] + [format_param(p) for p in params])
    if trid is None and not with_crc:
        return f"%R1P,{com_rc}:{body}".encode("ascii") + TERMINATOR
    trid = 0 if trid is None else trid
    if with_crc:
        crc = crc16(f"%R1P,{com_rc},{trid}:{body}")
        msg = f"%R1P,{com_rc},{trid},{crc}:{body}"
    else:
        msg = f"%R1P,{com_rc},{trid}:{body}"
    return msg.encode("ascii") + TERMINATOR


_REQ_RE = re.compile(r"^%R1Q,(\d+)(?:,(-?\d+))?(?:,(\d+))?:(.*)$")
_REP_RE = re.compile(r"^%R1P,(\d+)(?:,(-?\d+)(?:,(\d+))?)?:(\d+)?(?:,(.*))?$")
REPLY_START = "%R1P,"
REQUEST_START = "%R1Q,"


def decode_request(line: str) -> Request:
    """Decode a request line (without terminator). Raises ValueError if not a request."""
    m = _REQ_RE.match(line)
    if not m:
        raise ValueError(f"not a GeoCOM request: {line[:60]!r}")
    rpc = int(m.group(1))
    trid = int(m.group(2)) if m.group(2) is not None else None
    body = m.group(4)
    crc_present = m.group(3) is not None
    crc_ok = True
    if crc_present:
        crc_ok = crc16(f"%R1Q,{rpc},{m.group(2)}:{body}") == int(m.group(3))
    params = tuple(parse_param(p) for p in split_params(body)) if crc_ok else ()
    return Request(rpc, trid, params, crc_present, crc_ok)


def decode_reply(line: str, t_host: float = float("nan")) -> Reply:
    """Decode a reply line (without terminator), verifying its CRC-16 when present.

    Raises
    ------
    GeoComChecksumError : CRC field present and wrong (code 3102).
    GeoComProtocolError : not a GeoCOM reply (code 3094) or undecodable parameters (3074).
    """
    m = _REP_RE.match(line)
    if not m:
        raise GeoComProtocolError(3094, detail=f"not a GeoCOM reply: {line[:60]!r}")
    com_rc = int(m.group(1))
    trid = int(m.group(2)) if m.group(2) is not None else None
    rest = line[line.index(":") + 1:]
    if m.group(3) is not None:
        if crc16(f"%R1P,{m.group(1)},{m.group(2)}:{rest}") != int(m.group(3)):
            raise GeoComChecksumError(3102, detail=f"reply {line[:60]!r}")
    rc = int(m.group(4)) if m.group(4) is not None else com_rc
    try:
        params = tuple(parse_param(p) for p in split_params(m.group(5) or ""))
    except ValueError as e:
        raise GeoComProtocolError(3074, detail=f"bad parameter in {line[:60]!r}") from e
    return Reply(com_rc, trid, rc, params, m.group(3) is not None, t_host, line)
