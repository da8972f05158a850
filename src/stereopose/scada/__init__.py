"""The utility's own protocols: the site's alarms and states as a SCADA system reads them.

points: the one table of the IEC 60870-5-104 points (information object addresses, types,
what each means and where its value comes from), built from the site file and the rig, which
`stereopose points` prints. iec104: the outstation that serves them (needs the `scada` extra:
c104). opcua: the OPC UA server (asyncua). See docs/scada.md.
"""

from __future__ import annotations

from stereopose.scada.points import Point, PointsTable, cameras_seeing, points_table

__all__ = ["Point", "PointsTable", "cameras_seeing", "points_table"]
