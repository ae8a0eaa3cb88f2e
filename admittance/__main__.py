from admittance.cli import main

raise SystemExit(main())
