from landing_zone.tools.cli import main

main()
