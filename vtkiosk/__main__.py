from vtkiosk.cli import main

raise SystemExit(main())
