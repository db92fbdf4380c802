"""`rig commission`: the field source measured against the station's reference magnetometer (at the centre and
at more places, with the other references), and with --thermal what planning needs of the chamber and each DUT
position."""
