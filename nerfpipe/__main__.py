from nerfpipe.cli.main import main

main()
