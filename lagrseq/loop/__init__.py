"""The LaGR-SEQ loop and its parts: Algorithm 1 (experiment), the agents' adapters, LaGR's query and acceptance (lagr), SEQ's query reward (seq), the asking policies."""
