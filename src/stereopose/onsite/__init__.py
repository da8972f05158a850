"""Warnings on site: the hazards of the energized zones said on IP speakers (RTP, G.711) and
shown by beacons, sirens and relays (the coils of a Modbus TCP IO module), in the site's
language, with the hazard's distance and side from the worker's skeleton (onsite.warner).
The site file's `[warnings]`, `[[speakers]]` and `[[signals]]` (onsite.settings) say which."""
