"""A site's detection spread over several machines.

`stereopose detect-node` (nodes.node) opens some of the site's cameras, finds their people
and publishes each camera-frame's 2D people with its capture time on the site's broker;
`serve` with ``[input] detection = "nodes"`` (nodes.fusion) takes them from there, groups them
into time steps by capture time, and runs everything after detection as with its own cameras.
nodes.wire is what goes between them (topics and payloads); nodes.paced plays recorded files
at a node as live cameras on the wall clock, the same frame on every node at the same time.
"""
