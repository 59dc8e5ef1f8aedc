#include "dashboard/dashboard.hpp"

#include <nlohmann/json.hpp>

#include "dashboard/robot_description.hpp"

namespace pnp::dashboard {

Dashboard::Dashboard(mdns::Mdns* mdns, DashboardOptions options) : options_(std::move(options)) {
    web_ = std::make_unique<WebServer>(options_.web);
    cell_ = std::make_unique<CellView>(mdns, options_.cell,
                                       [this](std::string m) { web_->broadcast(std::move(m)); });
    actions_ = std::make_unique<Actions>(
        *cell_, options_.actions,
        [this](ClientId page, std::string m) { web_->send(page, std::move(m)); });
    web_->onApi([this](std::string_view path) -> std::optional<HttpReply> {
        if (path == "snapshot") return HttpReply{200, "application/json", cell_->snapshot().dump()};
        if (path == "robots")
            return HttpReply{200, "application/json", nlohmann::json(robotModels()).dump()};
        constexpr std::string_view kRobot = "robot/";
        if (path.substr(0, kRobot.size()) == kRobot) {
            if (auto d = robotDescription(path.substr(kRobot.size())))
                return HttpReply{200, "application/json", d->dump()};
        }
        return std::nullopt;
    });
    // A new page gets the whole state first; later broadcasts follow it in order.
    web_->onOpen([this](ClientId) { return cell_->snapshot().dump(); });
    web_->onMessage([this](ClientId page, std::string text) { actions_->handle(page, text); });
    web_->onClose([this](ClientId page) { actions_->pageClosed(page); });
}

Dashboard::~Dashboard() { stop(); }

void Dashboard::start() {
    web_->start();
    cell_->start();
}

void Dashboard::stop() {
    if (actions_) actions_->stop();
    if (cell_) cell_->stop();
    if (web_) web_->stop();
}

std::uint16_t Dashboard::port() const { return web_->port(); }

}  // namespace pnp::dashboard
