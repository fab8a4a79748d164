"""Read an A2L with pya2ldb (pyXCP's A2L database) and print what the tests compare, as JSON:
every CHARACTERISTIC and AXIS_PTS (address, conversion factor, limits), every MEASUREMENT, the
EPK, IF_DATA XCP's identifiers and events, and pya2ldb's validator's diagnostics.

    python tests/xcp/read_a2l.py FILE.a2l

Run as a process of its own: pya2ldb's parser reports syntax errors on the process's output
(the test looks for them there) and installs its own exception printer."""

from __future__ import annotations

import json
import sys

import pya2l
from pya2l import model
from pya2l.api.validate import Validator


def main(path: str) -> None:
    s = pya2l.import_a2l(path, in_memory=True, progress_bar=False, loglevel="WARN")
    factors = {
        c.name: (c.coeffs_linear.a if c.coeffs_linear is not None else None, c.unit)
        for c in s.query(model.CompuMethod)
    }
    characteristics = [
        {
            "name": c.name, "type": c.type, "address": c.address, "conversion": c.conversion,
            "factor": factors[c.conversion][0], "unit": factors[c.conversion][1],
            "lo": c.lowerLimit, "hi": c.upperLimit,
            "points": c.axis_descr[0].maxAxisPoints if c.axis_descr else 1,
        }
        for c in s.query(model.Characteristic)
    ]  # fmt: skip
    axis = [
        {"name": a.name, "address": a.address, "points": a.maxAxisPoints,
         "factor": factors[a.conversion][0]}
        for a in s.query(model.AxisPts)
    ]  # fmt: skip
    measurements = [
        {"name": m.name, "address": m.ecu_address.address, "type": m.datatype,
         "factor": factors[m.conversion][0]}
        for m in s.query(model.Measurement)
    ]  # fmt: skip
    mod_par = s.query(model.ModPar).one()
    module = s.query(model.Module).one()
    xcp = s.parse_ifdata(module.if_data)[0]["XCP"]
    common, can = xcp[0], xcp[1]["XCP_ON_CAN"][0][1]
    out = {
        "characteristics": characteristics,
        "axis_pts": axis,
        "measurements": measurements,
        "epk": [mod_par.addr_epk[0].address, mod_par.epk.identifier],
        "can": [can["CAN_ID_MASTER"], can["CAN_ID_SLAVE"]],
        "events": common["DAQ"][10]["EVENT"],
        "protocol": common["PROTOCOL_LAYER"][:12],
        "diagnostics": [m.text for m in Validator(s, loglevel="ERROR")()],
    }
    print("JSON " + json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1])
