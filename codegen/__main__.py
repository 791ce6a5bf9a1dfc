from codegen.cli.main import main

if __name__ == "__main__":  # not when verify's comparing process (spawned) imports it again
    raise SystemExit(main())
