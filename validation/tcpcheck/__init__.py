"""The TCP model against kernel TCP: one workload, on the same profile and seed, two ways.

(a) The model (`model`): a `Link` with transport tcp, driven with made-up times (a second of CPU).
(b) Kernel TCP (`kernel`) between two namespaces of a throw-away lab (`launch.lab.Lab`), each
    direction shaped by its sender's TUN shaper (`abyss link shape`, the same stages as the model's
    link: data one way, acknowledgements the other). The `programs` module's `send` and `receive`
    run in the namespaces (`ip netns exec`); CLOCK_MONOTONIC is shared across network namespaces,
    so the receiver measures one-way latency against the sender's schedule directly, and the
    sender's namespace counters (/proc/net/snmp, /proc/net/netstat) count its retransmissions
    (RetransSegs), timeouts (TCPTimeouts) and first transmissions (TCPOrigDataSent).

A case's workload (`workload`), each phase on a new connection (and a new model link): a bulk
transfer (goodput, retransmissions and timeouts per packet) and streams of 1, 10 and 100 kB
messages at a pace the link carries (delivery latency p50/p95: from when a message was due to when
its last byte reached the receiving application). `compare` makes the runs and weighs them.
"""
