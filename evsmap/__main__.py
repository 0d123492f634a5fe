from evsmap.cli.main import main

raise SystemExit(main())
