// The dashboard (docs/dashboard.md): the cell's OPC UA view (CellView) pushed to pages over
// a WebSocket (WebServer), the pages' actions (Actions), the robots' geometry.
//
//   Dashboard dashboard(&mdns, {.web = {.port = 8080, .assets = dir}, .cell = {.ldsUrls = {lds}}});
//   dashboard.start();
//   std::cout << "dashboard on http://127.0.0.1:" << dashboard.port() << "/\n";
#pragma once

#include <cstdint>
#include <memory>

#include "dashboard/actions.hpp"
#include "dashboard/cell_view.hpp"
#include "dashboard/web_server.hpp"
#include "mdns/mdns.hpp"

namespace pnp::dashboard {

struct DashboardOptions {
    WebServerOptions web;
    CellViewOptions cell;
    ActionOptions actions;
};

class Dashboard {
  public:
    Dashboard(mdns::Mdns* mdns, DashboardOptions options);  // mdns may be null
    ~Dashboard();                                           // stop()
    Dashboard(const Dashboard&) = delete;
    Dashboard& operator=(const Dashboard&) = delete;

    // The web server first (throws std::runtime_error when the port is taken), then the view.
    void start();
    void stop();
    std::uint16_t port() const;
    const CellView& cell() const { return *cell_; }

  private:
    DashboardOptions options_;
    std::unique_ptr<WebServer> web_;
    std::unique_ptr<CellView> cell_;
    std::unique_ptr<Actions> actions_;
};

}  // namespace pnp::dashboard
