from stereogeo_cli.cli import main

main()
