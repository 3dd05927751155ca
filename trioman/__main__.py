from trioman.cli import main

raise SystemExit(main())
