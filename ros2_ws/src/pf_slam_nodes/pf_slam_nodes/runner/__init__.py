"""The parts of `pf-slam run` (graph.run) by concern: params, inputs and mount (bag inspection),
recorder, supervise, outputs; common holds what they share."""
