from pipeline.synth.cli import main

raise SystemExit(main())
