"""The study commands: reproduce the paper's suite, the audits, the query-efficiency frontier, the authors' recorded answers, the accuracy probe."""
