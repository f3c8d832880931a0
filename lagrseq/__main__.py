from lagrseq.cli import main

raise SystemExit(main())
