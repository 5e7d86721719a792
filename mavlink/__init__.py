"""The vehicle as a MAVLink system, as ArduSub presents one (docs/mavlink.md): `vehicle` is
onboard's MAVLink side (the modes, arming, the failsafes, mapped onto onboard's own goals),
`streams` what it sends, `mission` and `params` the protocols a ground station runs with it,
`ardusub` the autopilot's numbers, `geodesy` the site's world frame on the Earth, and `endpoint`
the UDP endpoints the vessel and the onshore station serve to ground stations."""
